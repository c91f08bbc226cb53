"""A prior for the head: what the pair seeds say, used as a Gaussian prior on a seed's own head fit.

MDM replaces a seed's head with a mapper's; a prior only pulls the seed's fit toward a mean head,
as far as the seed's own data leaves the head undecided. A :class:`HeadPrior` has

- a **mean**: a mapper's prediction from the seed's w_BC (and context, where its kind reads
  one): a learned kind's is the MetaL prior; the control kinds' are pi*'s head and mean-DA (the
  training pairs' mean w_DA); and :data:`ZERO`, no mapper, is weight decay with a strength per
  coordinate;
- a **precision** per coordinate: the inverse of the variance of the training pairs' w_DA around
  their means (the mapper's predictions for them), floored at :data:`VARIANCE_FLOOR` times its
  mean over the coordinates;
- a **strength** ``lam``, chosen on the validation pairs alone (:func:`choose_strengths`) from a
  grid that runs from plain BC (0) through the fixed :data:`STRENGTHS` to the prior's limit, the
  mean head itself (:data:`LIMIT`, an infinite strength: no fit at all). Each validation seed's
  demonstration is fitted, as the pairs fitted it, once per finite strength, and the strength whose
  heads land nearest the seeds' w_DA (mean squared distance) is kept, a tie going to the weaker.
  While the largest finite strength is kept, the grid grows past it tenfold at a time (at most
  :data:`EXTENSIONS` times), so that the choice does not sit at the grid's edge unseen; one rule
  for every mean. Adam moves a weight by about the learning rate a step, so a fit from the fresh
  head pulled however hard stops short of a far mean: the limit is what reaches it.

The fit's loss is then the data's plus ``(lam / 2) * sum_j p_j (w_j - m_j)^2``
(:class:`~metadagger.imitation.head_fits.Prior`; docs/method.md, "A prior for the head"). The
same rule serves every mean, so the priors differ only in where they pull.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, head_fit
from metadagger.imitation.head_fits import HeadFit, Prior, fit_heads
from metadagger.mapping.mappers import Mapper
from metadagger.metal_dagger.method import SeedLearner, demonstration, seeded
from metadagger.metal_dagger.store import PairSplit
from metadagger.runfolder.stamps import data_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.utils.io import read_json, write_json

#: The mean of a prior without a mapper: the zero head.
ZERO = "zero"
#: The finite strengths ``lam`` a prior is first chosen from, weakest first; fixed in advance (0: no prior).
STRENGTHS = (0.0, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: The grid's last point, after every finite strength: the mean head itself (no fit), as records name it.
LIMIT = "limit"
#: How many times the grid grows tenfold past its largest finite strength while that one is kept.
EXTENSIONS = 4
#: The floor of a coordinate's variance, as a share of the variances' mean over the coordinates.
VARIANCE_FLOOR = 1e-2


@dataclass(frozen=True)
class HeadPrior:
    """A Gaussian prior on a head: the mapper kind of its mean (:data:`ZERO` for none), the
    precision per coordinate and the strength."""

    mean: str
    precision: torch.Tensor
    strength: float = 0.0
    limit: bool = False
    """At the grid's limit: the head is the mean itself, whatever the data (``strength`` unused)."""

    def prior(self, mean_head: torch.Tensor) -> Prior:
        """The kernel's prior for a seed whose mean head is ``mean_head`` (:func:`mean_head`)."""
        weight = (self.strength * self.precision).to(torch.float32)
        return Prior(mean=mean_head.to(torch.float32), weight=weight, pinned=self.limit)

    @property
    def setting(self) -> float | str:
        """The strength as records write it: a number, or :data:`LIMIT`."""
        return LIMIT if self.limit else self.strength


def mean_head(mapper: Mapper | None, w_bc: torch.Tensor, context: torch.Tensor | None = None) -> torch.Tensor:
    """A seed's prior mean: ``mapper``'s head for its ``w_bc`` (and ``context``), or zero without a mapper."""
    w_bc = torch.as_tensor(w_bc, dtype=torch.float32)
    if mapper is None:
        return torch.zeros_like(w_bc)
    return mapper.map_tensor(w_bc[None], None if context is None else torch.as_tensor(context)[None])[0].clone()


def residual_precision(residuals: torch.Tensor) -> torch.Tensor:
    """Per-coordinate precision from residuals ``[n, d]`` (w_DA minus the mean, per training pair):
    the inverse of each coordinate's mean square, floored at :data:`VARIANCE_FLOOR` times their mean."""
    if residuals.ndim != 2 or len(residuals) < 2:
        raise UserError(
            f"a prior's precision needs at least 2 training pairs, got residuals of shape {tuple(residuals.shape)}"
        )
    variance = residuals.double().square().mean(dim=0)
    floor = VARIANCE_FLOOR * float(variance.mean())
    if not floor > 0.0:
        raise UserError("the training pairs' w_DA do not vary around the prior's mean; a prior needs pairs that differ")
    return (1.0 / variance.clamp_min(floor)).to(torch.float32)


def build_prior(split: PairSplit, mapper: Mapper | None) -> HeadPrior:
    """The prior whose mean is ``mapper``'s map (zero without one), its precision from the training
    pairs of ``split``, at strength 0 (choose it with :func:`choose_strengths`)."""
    w_da = split.w_da_train.to(torch.float32)
    if mapper is None:
        means = torch.zeros_like(w_da)
    else:
        means = mapper.map_tensor(split.w_bc_train.to(torch.float32), split.context_train)
    return HeadPrior(mean=ZERO if mapper is None else mapper.kind, precision=residual_precision(w_da - means))


@dataclass(frozen=True)
class StrengthChoice:
    """The strength :func:`choose_strengths` kept (a number, or :data:`LIMIT`), each strength's mean
    squared distance to w_DA, and whether the kept one is the grid's largest finite strength."""

    strength: float | str
    distances: dict[float | str, float]
    edge: bool = False
    """The kept strength is the largest finite one even after :data:`EXTENSIONS` extensions."""

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON data for a stamp or a report."""
        return {
            "strength": self.strength,
            "distances": {_name(k): v for k, v in self.distances.items()},
            "edge": self.edge,
        }


def _name(strength: float | str) -> str:
    return strength if isinstance(strength, str) else f"{strength:g}"


@dataclass(frozen=True)
class _ValidationSeed:
    """One validation seed's plain fit (its demonstration, as the pairs fitted it), target and means."""

    base: HeadFit
    target: torch.Tensor
    means: dict[str, torch.Tensor]
    """Each prior's mean head for the seed, by the prior's mean."""
    out_dim: int
    discrete: bool


def choose_strengths(
    priors: Mapping[str, tuple[HeadPrior, Mapper | None]],
    task: Task,
    pistar: str,
    split: PairSplit,
    fit: BCConfig,
    *,
    strengths: Sequence[float] = STRENGTHS,
) -> dict[str, tuple[HeadPrior, StrengthChoice]]:
    """Each prior (with the mapper of its mean, None for zero) at the strength whose fits of the
    validation seeds' demonstrations land nearest their w_DA, and the distances of every strength.

    The grid is ``strengths``, then :data:`LIMIT` (the mean head itself); while a prior keeps its
    grid's largest finite strength, that grid grows tenfold past it (:data:`EXTENSIONS` times at
    most). Each validation seed's demonstration is made once and fitted as the pairs fitted it
    (``fit``, seeded by the seed, from the seed's fresh head), once per prior and strength, batched
    in one kernel call; no seed outside the validation split is read.
    """
    if not split.val_seeds:
        raise UserError("choosing a prior's strength needs validation pairs; keep some (pairs' split)")
    seeds = []
    for row, seed in enumerate(split.val_seeds):
        context = None if split.context_val is None else split.context_val[row]
        with SeedLearner(task, pistar, seed, head_init_seed=fit.head_init_seed(seed)) as learner:
            data = demonstration(learner).to_dataset()
            base = head_fit(
                learner.policy, data, seeded(fit, seed), learner.cache, called=f"the prior fit of pair seed {seed}"
            )
            out_dim, discrete = int(learner.policy.net.head.out_features), learner.policy.discrete
        means = {mean: mean_head(mapper, split.w_bc_val[row], context) for mean, (_, mapper) in priors.items()}
        seeds.append(_ValidationSeed(base, split.w_da_val[row].to(torch.float32), means, out_dim, discrete))
    distances = _distances(priors, seeds, strengths)
    for mean in priors:  # the limit: the mean head itself, no fit
        gaps = [float((v.means[mean] - v.target).double().square().mean()) for v in seeds]
        distances[mean][LIMIT] = sum(gaps) / len(gaps)
    chosen = {}
    for mean, (prior, mapper) in priors.items():
        grid = [float(lam) for lam in strengths]
        for _ in range(EXTENSIONS):
            if _best(distances[mean]) != grid[-1] or grid[-1] == 0.0:
                break
            grid.append(grid[-1] * 10)
            distances[mean].update(_distances({mean: (prior, mapper)}, seeds, grid[-1:])[mean])
        best = _best(distances[mean])
        kept = _kept(prior, best)
        ordered = {k: distances[mean][k] for k in [*grid, LIMIT]}
        chosen[mean] = (kept, StrengthChoice(best, ordered, edge=best == grid[-1] and grid[-1] > 0.0))
    return chosen


def _best(distances: Mapping[float | str, float]) -> float | str:
    """The strength of the least distance, a tie going to the weaker (the limit is the strongest)."""
    order = {k: i for i, k in enumerate(sorted((k for k in distances if k != LIMIT), key=float))}
    order[LIMIT] = len(order)
    return min(distances, key=lambda k: (distances[k], order[k]))


def _distances(
    priors: Mapping[str, tuple[HeadPrior, Mapper | None]],
    seeds: list[_ValidationSeed],
    strengths: Sequence[float],
) -> dict[str, dict[float | str, float]]:
    """Each prior's mean squared distance to w_DA over ``seeds`` at each of ``strengths`` (finite),
    its fits batched."""
    totals = {mean: np.zeros(len(strengths)) for mean in priors}
    for v in seeds:
        requests = [
            dataclasses.replace(v.base, prior=dataclasses.replace(prior, strength=lam).prior(v.means[mean]))
            for mean, (prior, _) in priors.items()
            for lam in strengths
        ]
        heads = iter(fit_heads(requests, out_dim=v.out_dim, discrete=v.discrete))
        for mean in priors:
            totals[mean] += [float((next(heads).head - v.target).double().square().mean()) for _ in strengths]
    return {
        mean: {float(lam): float(total / len(seeds)) for lam, total in zip(strengths, totals[mean])} for mean in priors
    }


def _kept(prior: HeadPrior, strength: float | str) -> HeadPrior:
    """``prior`` at a recorded strength: a number, or :data:`LIMIT`."""
    if strength == LIMIT:
        return dataclasses.replace(prior, strength=0.0, limit=True)
    return dataclasses.replace(prior, strength=float(strength))


def split_fingerprint(split: PairSplit) -> str:
    """A short hash of everything a prior is built and chosen from in ``split``: its seeds and heads."""
    tensors = [
        split.w_bc_train,
        split.w_da_train,
        split.w_bc_val,
        split.w_da_val,
        split.context_train,
        split.context_val,
    ]
    arrays = [b"" if t is None else t.to(torch.float32).contiguous().numpy().tobytes() for t in tensors]
    return data_fingerprint(list(split.train_seeds), list(split.val_seeds), *arrays)


def chosen_priors(
    means: Mapping[str, Mapper | None],
    task: Task,
    pistar: str,
    split: PairSplit,
    fit: BCConfig,
    *,
    record: Path,
    inputs: Mapping[str, Any],
    progress: bool = False,
) -> dict[str, HeadPrior]:
    """The prior toward each of ``means`` (a mapper, or None for zero), built from ``split``'s
    training pairs, at the strength :func:`choose_strengths` keeps on its validation pairs.

    The choice is written to ``record`` (JSON: its stamp and each mean's
    :meth:`StrengthChoice.as_dict`) and read back instead of made again while it was made from the
    same ``inputs`` (the caller's: pi*, the mappers, the kernels), split, fit and grid, for every mean.
    """
    stamp = {
        **inputs,
        "split": split_fingerprint(split),
        "fit": stamp_of(fit),
        "strengths": [*STRENGTHS, LIMIT],
        "extensions": EXTENSIONS,
        "variance_floor": VARIANCE_FLOOR,
    }
    built = {mean: build_prior(split, mapper) for mean, mapper in means.items()}
    made = read_json(record, "the priors' strengths") if record.is_file() else None
    if made is not None and made.get("stamp") == stamp and set(means) <= set(made.get("chosen", {})):
        return {mean: _kept(p, made["chosen"][mean]["strength"]) for mean, p in built.items()}
    if progress:
        print(f"priors: choosing strengths on {len(split.val_seeds)} validation pairs", file=sys.stderr, flush=True)
    chosen = choose_strengths({mean: (built[mean], mapper) for mean, mapper in means.items()}, task, pistar, split, fit)
    write_json(record, {"stamp": stamp, "chosen": {mean: choice.as_dict() for mean, (_, choice) in chosen.items()}})
    return {mean: prior for mean, (prior, _) in chosen.items()}


__all__ = [
    "EXTENSIONS",
    "LIMIT",
    "STRENGTHS",
    "VARIANCE_FLOOR",
    "ZERO",
    "HeadPrior",
    "StrengthChoice",
    "build_prior",
    "choose_strengths",
    "chosen_priors",
    "mean_head",
    "residual_precision",
    "split_fingerprint",
]
