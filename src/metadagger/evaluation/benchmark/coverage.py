"""Where a seed's demonstration says little: its coverage gap, and whether the gap predicts what a
mapper adds over its constant twin.

Knowledge from other seeds can help a seed only where the seed's own data leaves its head
undecided: the feature directions its demonstration barely covers. The **coverage gap** of a seed
(docs/benchmark.md, "Coverage") measures how much of the states DAgger then visits lies there:

- centre the demonstration's trunk features at their mean and take the principal directions that
  hold :data:`VARIANCE_SHARE` of their variance;
- centre the DAgger states' features at the same mean (a shift of the mean counts as uncovered
  unless the directions span it);
- the gap is the share of those states' energy (sum of squares) outside the directions, in [0, 1].

:func:`gap_against_gain` then asks, over the unseen seeds, whether a larger gap goes with a larger
gain of a MetaL DAgger method over its constant twin: Spearman's rank correlation, with its
two-sided p-value.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import torch
from scipy import stats

#: The share of the demonstration's feature variance its leading principal directions hold.
VARIANCE_SHARE = 0.95


def coverage_gap(demonstration: torch.Tensor, visited: torch.Tensor, *, share: float = VARIANCE_SHARE) -> float:
    """The share of the energy of ``visited`` [N, F] (centred at the demonstration's mean) outside the
    principal directions holding ``share`` of the variance of ``demonstration`` [M, F]; 0 where
    ``visited`` holds no energy about that mean."""
    if demonstration.ndim != 2 or visited.ndim != 2 or demonstration.shape[1] != visited.shape[1]:
        raise ValueError(
            f"features must be [M, F] and [N, F] of one width, got {tuple(demonstration.shape)} and "
            f"{tuple(visited.shape)}"
        )
    demo = demonstration.double()
    mean = demo.mean(dim=0)
    _, singular, directions = torch.linalg.svd(demo - mean, full_matrices=False)
    variance = singular.square()
    total = float(variance.sum())
    kept = 0 if total == 0.0 else int(torch.searchsorted(variance.cumsum(0) / total, share).item()) + 1
    basis = directions[: min(kept, len(directions))]
    centred = visited.double() - mean
    energy = float(centred.square().sum())
    if energy == 0.0:
        return 0.0
    inside = float((centred @ basis.T).square().sum())
    return min(max(1.0 - inside / energy, 0.0), 1.0)


def gap_against_gain(gaps: Sequence[float], gains: Sequence[float]) -> dict[str, Any]:
    """Spearman's rank correlation of the seeds' coverage gaps with a method's paired gains, its
    two-sided p-value and the seed count; ``rho`` and ``p_value`` are None where either side is
    constant (nothing to rank)."""
    if len(gaps) != len(gains):
        raise ValueError(f"{len(gaps)} gaps for {len(gains)} gains")
    seeds = len(gaps)
    if seeds < 3 or len(set(gaps)) < 2 or len(set(gains)) < 2:
        return {"seeds": seeds, "rho": None, "p_value": None}
    rho, p_value = stats.spearmanr(np.asarray(gaps), np.asarray(gains))
    if not (math.isfinite(rho) and math.isfinite(p_value)):
        return {"seeds": seeds, "rho": None, "p_value": None}
    return {"seeds": seeds, "rho": float(rho), "p_value": float(p_value)}


def rank_interval(rho: float | None, seeds: int, *, level: float = 0.95) -> tuple[float, float] | None:
    """The ``level`` interval of Spearman's rho over ``seeds`` seeds: Fisher's z with Bonett and
    Wright's variance, (1 + rho^2 / 2) / (seeds - 3); None without a rho or with fewer than 4 seeds."""
    if rho is None or seeds < 4:
        return None
    z = math.atanh(min(max(rho, -0.999999), 0.999999))
    half = stats.norm.ppf(0.5 + level / 2) * math.sqrt((1 + rho**2 / 2) / (seeds - 3))
    return math.tanh(z - half), math.tanh(z + half)


__all__ = ["VARIANCE_SHARE", "coverage_gap", "gap_against_gain"]
