"""Gates that remember the run: thresholds set from every earlier round of one DAgger run.

- ``thrifty(rate)``: ThriftyDAgger's two tests (Hoque et al., CoRL 2021), novelty and risk, each
  above the ``1 - rate`` quantile of every estimate of the run so far.
- ``conformal(alpha)``: CRSAIL's rule (arXiv 2512.00453), a neighbour distance above one threshold
  calibrated by conformal prediction on the first round's states, then kept.

What they remember is in the run's :class:`~metadagger.imitation.gate_view.GateMemory`; the interface
and the other gates are in :mod:`metadagger.imitation.gates`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from metadagger.imitation.gate_view import Episode, LearnerView, Selection
from metadagger.imitation.gates import (
    Gate,
    bootstrap_outputs,
    check_count,
    check_ridge,
    check_share,
    neighbour_distance,
    ridge_weights,
    with_bias,
)


@dataclass(frozen=True)
class ThriftyGate(Gate):
    """ThriftyDAgger's query rule: label a state that is novel or risky.

    Novelty is the variance of ``K`` bootstrap ridge heads' outputs, summed over output dimensions
    (one-hot class scores for a discrete task). Risk is one minus a ridge regression's estimate,
    on the trunk features, that an episode through the state succeeds, fitted on every state of
    the run's finished episodes (the demonstration and the rollouts of earlier rounds) with its
    episode's outcome; while those episodes hold one outcome only there is nothing to learn risk
    from, and novelty decides alone. Each threshold is the ``1 - rate`` quantile of that
    estimate over every state the run's gate has scored so far (this round's included), so at
    most about ``2 * rate`` of the states are labelled, fewer as the learner's states grow
    familiar.
    """

    setting: ClassVar[str] = "rate"
    rate: float
    """The target share of states each test flags, in (0, 1)."""
    K: int = 5
    """Bootstrap heads of the novelty test, >= 2."""
    ridge: float = 1e-3
    """Ridge penalty of the novelty heads, relative to the features' mean energy, > 0."""
    risk_ridge: float = 0.1
    """Ridge penalty of the risk estimate (smoothing noisy 0/1 outcomes, as the safe gate's), > 0."""

    def __post_init__(self) -> None:
        check_share("ThriftyGate.rate", self.rate)
        check_count("ThriftyGate.K", self.K, 2)
        check_ridge("ThriftyGate", self.ridge)
        check_ridge("ThriftyGate.risk", self.risk_ridge)

    def select(self, view: LearnerView) -> Tensor:
        """The states novel or risky by the run's thresholds, this round's estimates added to the record."""
        record = view.memory.notes.setdefault("thrifty", {"novelty": [], "risk": []})
        heads = bootstrap_outputs(view.features, view.labelled, self.K, self.ridge, view.generator)
        novelty = heads.var(dim=0, unbiased=False).sum(dim=1)
        record["novelty"].append(novelty)
        mask = novelty > torch.quantile(torch.cat(record["novelty"]), 1.0 - self.rate)
        risk = self.risk(view.features, view.memory.episodes)
        if risk is not None:
            record["risk"].append(risk)
            mask |= risk > torch.quantile(torch.cat(record["risk"]), 1.0 - self.rate)
        return mask

    def risk(self, features: Tensor, episodes: list[Episode]) -> Tensor | None:
        """One minus the estimated chance that an episode through each state succeeds [N]; None
        while the finished ``episodes`` hold one outcome only."""
        if len({e.succeeded for e in episodes}) < 2:
            return None
        seen = torch.cat([e.features for e in episodes])
        outcome = torch.cat(
            [torch.full((len(e.features), 1), float(e.succeeded), dtype=torch.float64) for e in episodes]
        )
        return 1.0 - (with_bias(features) @ ridge_weights(seen, outcome, self.risk_ridge)).squeeze(1)


def conformal_threshold(scores: Tensor, alpha: float) -> float:
    """The split-conformal threshold of calibration ``scores`` at miscoverage ``alpha``: the
    ceil((n + 1)(1 - alpha))-th smallest score (infinite when that rank exceeds n), which a new
    score from the same distribution exceeds with probability at most ``alpha``."""
    n = len(scores)
    rank = math.ceil((n + 1) * (1.0 - alpha))
    return math.inf if rank > n else float(scores.double().sort().values[rank - 1])


@dataclass(frozen=True)
class ConformalGate(Gate):
    """CRSAIL's query rule: label a state far from every labelled one, by one calibrated threshold.

    The score is the distance to the ``k``-th nearest labelled state (the novelty gate's). In the
    run's first round the threshold is calibrated once (:func:`conformal_threshold`) on that
    round's scores, the first policy's rollout against the demonstration, and then kept: later
    rounds label only the states farther than it from everything labelled by then.
    """

    setting: ClassVar[str] = "alpha"
    alpha: float
    """Miscoverage: about this share of the first round's states is labelled, in (0, 1)."""
    k: int = 1
    """Which nearest labelled neighbour measures the distance, >= 1."""

    def __post_init__(self) -> None:
        check_share("ConformalGate.alpha", self.alpha)
        check_count("ConformalGate.k", self.k, 1)

    def select(self, view: LearnerView) -> Selection:
        """The states farther from everything labelled than the threshold the run's first round set."""
        scores = neighbour_distance(view.features, view.labelled, self.k, "ConformalGate")
        notes = view.memory.notes
        if "conformal" not in notes:
            notes["conformal"] = conformal_threshold(scores, self.alpha)
        return Selection(scores.double() > notes["conformal"], scores)
