"""A prior for the head: what the pair seeds say, used as a Gaussian prior on a seed's own head fit.

MDM replaces a seed's head with a mapper's; a prior only pulls the seed's fit toward a mean head,
as far as the seed's own data leaves the head undecided. A :class:`HeadPrior` has

- a **mean**, one of :data:`PRIOR_MEANS`: the mapper's prediction from the seed's w_BC (and
  context, where its kind reads one), the MetaL prior; or, as controls, pi*'s head, mean-DA (the
  training pairs' mean w_DA) and zero (weight decay with a strength per coordinate);
- a **precision** per coordinate: the inverse of the variance of the training pairs' w_DA around
  the mean (their residuals around the mapper's predictions, for the mapper), floored at
  :data:`VARIANCE_FLOOR` times its mean over the coordinates;
- a **strength** ``lam``, chosen from the fixed grid :data:`STRENGTHS` on the validation pairs
  alone (:func:`choose_strength`): each validation seed's demonstration is fitted, as the pairs
  fitted it, once per strength, and the strength whose heads land nearest the seeds' w_DA (mean
  squared distance) is kept, a tie going to the weaker.

The fit's loss is then the data's plus ``(lam / 2) * sum_j p_j (w_j - m_j)^2``
(:class:`~metadagger.imitation.head_fits.Prior`; docs/method.md, "A prior for the head"). The
same rule serves every mean, so the four differ only in where they pull.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, head_fit
from metadagger.imitation.head_fits import Prior, fit_heads
from metadagger.mapping.mappers import Mapper
from metadagger.metal.method import SeedLearner, demonstration, seeded
from metadagger.metal.store import PairSplit
from metadagger.tasks.base import Task

#: The means a prior can pull toward: the mapper's prediction (the MetaL prior), then the controls.
PRIOR_MEANS = ("mapper", "pistar-head", "mean-da", "zero")
#: The strengths ``lam`` a prior is chosen from, weakest first; fixed in advance (0: no prior).
STRENGTHS = (0.0, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: The floor of a coordinate's variance, as a share of the variances' mean over the coordinates.
VARIANCE_FLOOR = 1e-2


@dataclass(frozen=True)
class HeadPrior:
    """A Gaussian prior on a head: its mean's kind, the constant mean (None for the mapper's, which
    depends on the seed), the precision per coordinate and the strength."""

    mean: str
    constant: torch.Tensor | None
    precision: torch.Tensor
    strength: float = 0.0

    def prior(self, mean_head: torch.Tensor) -> Prior:
        """The kernel's prior for a seed whose mean head is ``mean_head`` (:meth:`mean_for`)."""
        return Prior(mean=mean_head.to(torch.float32), weight=(self.strength * self.precision).to(torch.float32))

    def mean_for(self, w_bc: torch.Tensor, context: torch.Tensor | None, mapper: Mapper | None) -> torch.Tensor:
        """The mean head of a seed with head ``w_bc`` (and ``context``): the constant, or ``mapper``'s map."""
        if self.constant is not None:
            return self.constant
        if mapper is None:
            raise ValueError("the mapper prior needs its mapper")
        return mapper.map_tensor(w_bc[None].to(torch.float32), None if context is None else context[None])[0]


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


def build_prior(mean: str, split: PairSplit, *, mapper: Mapper | None, pistar_head: torch.Tensor) -> HeadPrior:
    """The prior of ``mean`` (one of :data:`PRIOR_MEANS`) from the training pairs of ``split``, at
    strength 0 (choose it with :func:`choose_strength`)."""
    if mean not in PRIOR_MEANS:
        raise UserError(f"unknown prior mean {mean!r}; expected one of {', '.join(PRIOR_MEANS)}")
    w_da = split.w_da_train.to(torch.float32)
    constant: torch.Tensor | None
    if mean == "mapper":
        if mapper is None:
            raise UserError("the mapper prior needs a mapper; train one first (metadagger train-mapper)")
        constant, means = None, mapper.map_tensor(split.w_bc_train.to(torch.float32), split.context_train)
    else:
        constant = {
            "pistar-head": pistar_head.to(torch.float32),
            "mean-da": w_da.mean(dim=0),
            "zero": torch.zeros(w_da.shape[1]),
        }[mean]
        means = constant.expand_as(w_da)
    return HeadPrior(mean=mean, constant=constant, precision=residual_precision(w_da - means))


@dataclass(frozen=True)
class StrengthChoice:
    """The strength :func:`choose_strength` kept, and each strength's mean squared distance to w_DA."""

    strength: float
    distances: dict[float, float]

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON data for a stamp or a report."""
        return {"strength": self.strength, "distances": {f"{k:g}": v for k, v in self.distances.items()}}


def choose_strength(
    prior: HeadPrior,
    task: Task,
    groundtruth: str,
    split: PairSplit,
    fit: BCConfig,
    *,
    mapper: Mapper | None = None,
    strengths: Sequence[float] = STRENGTHS,
) -> tuple[HeadPrior, StrengthChoice]:
    """``prior`` at the strength whose fits of the validation seeds' demonstrations land nearest
    their w_DA, and the distances of every strength.

    Each validation seed's demonstration is fitted as the pairs fitted it (``fit``, seeded by the
    seed, from the seed's fresh head), once per strength, the strengths batched in one kernel call;
    no seed outside the validation split is read.
    """
    if not split.val_seeds:
        raise UserError("choosing a prior's strength needs validation pairs; keep some (pairs' split)")
    totals = np.zeros(len(strengths))
    for row, seed in enumerate(split.val_seeds):
        seed_fit = seeded(fit, seed)
        context = None if split.context_val is None else split.context_val[row]
        mean_head = prior.mean_for(split.w_bc_val[row], context, mapper)
        with SeedLearner(task, groundtruth, seed, head_init_seed=fit.head_init_seed(seed)) as learner:
            data = demonstration(learner).to_dataset()
            base = head_fit(learner.policy, data, seed_fit, learner.cache, called=f"the prior fit of pair seed {seed}")
        requests = [
            dataclasses.replace(base, prior=dataclasses.replace(prior, strength=lam).prior(mean_head))
            for lam in strengths
        ]
        out_dim = int(learner.policy.net.head.out_features)
        heads = fit_heads(requests, out_dim=out_dim, discrete=learner.policy.discrete)
        target = split.w_da_val[row].to(torch.float32)
        totals += [float((fitted.head - target).double().square().mean()) for fitted in heads]
    distances = {float(lam): float(total / len(split.val_seeds)) for lam, total in zip(strengths, totals)}
    best = min(strengths, key=lambda lam: (distances[float(lam)], lam))
    return dataclasses.replace(prior, strength=float(best)), StrengthChoice(float(best), distances)


__all__ = [
    "PRIOR_MEANS",
    "STRENGTHS",
    "VARIANCE_FLOOR",
    "HeadPrior",
    "StrengthChoice",
    "build_prior",
    "choose_strength",
    "residual_precision",
]
