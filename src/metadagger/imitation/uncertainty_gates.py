"""Uncertainty sampling: gates that ask where the learner's own class distribution is unsure.

The oldest query rules of active learning (Lewis and Gale 1994; Settles's survey, 2009), and where
every comparison of interactive imitation learning starts. Each scores a state from the learner's
class distribution there, p = softmax(logits) (:meth:`~metadagger.imitation.gate_view.LearnerView.probabilities`),
and labels the states strictly above the round's ``quantile`` of the scores, as every score gate:

- ``least-confidence``: 1 - max p;
- ``margin``: 1 - (p(1) - p(2)), the two largest probabilities;
- ``entropy``: -sum p log p.

They read nothing but the learner's outputs, so they serve classification heads alone: on a task
with action vectors the benchmark refuses them before any work
(:func:`~metadagger.imitation.gate_registry.check_gates_serve`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar

import torch
from torch import Tensor

from metadagger.imitation.gate_view import LearnerView
from metadagger.imitation.gates import ScoreGate, check_quantile


def least_confidence(probabilities: Tensor) -> Tensor:
    """1 - the largest class probability of each row [N] of ``probabilities`` [N, C]."""
    return 1.0 - probabilities.max(dim=1).values


def margin(probabilities: Tensor) -> Tensor:
    """1 - the gap between the two largest class probabilities of each row [N]; 0 for a single class."""
    if probabilities.shape[1] < 2:
        return probabilities.new_zeros(len(probabilities))
    top = probabilities.topk(2, dim=1).values
    return 1.0 - (top[:, 0] - top[:, 1])


def entropy(probabilities: Tensor) -> Tensor:
    """The entropy -sum p log p of each row [N], in nats (0 log 0 = 0)."""
    # xlogy takes libm's log, element by element: Tensor.log is MKL's vector math, whose bits depend on the CPU
    return -torch.special.xlogy(probabilities, probabilities).sum(dim=1)


@dataclass(frozen=True)
class UncertaintyGate(ScoreGate):
    """A score gate on the learner's class distribution (a subclass names its score in ``measure``)."""

    needs_classes: ClassVar[bool] = True
    measure: ClassVar[Callable[[Tensor], Tensor]]
    """The score of each row [N] of a class distribution [N, C]."""
    quantile: float
    """Scores strictly above this quantile of the round's scores are labelled, in [0, 1)."""

    def __post_init__(self) -> None:
        check_quantile(type(self).__name__, self.quantile)

    def scores(self, view: LearnerView) -> Tensor:
        """The uncertainty of the learner's class distribution at each state [N]."""
        return self.measure(view.probabilities())


@dataclass(frozen=True)
class LeastConfidenceGate(UncertaintyGate):
    """Label where the learner's most likely class is least likely: 1 - max p."""

    measure = staticmethod(least_confidence)


@dataclass(frozen=True)
class MarginGate(UncertaintyGate):
    """Label where the learner's two most likely classes are closest: 1 - (p(1) - p(2))."""

    measure = staticmethod(margin)


@dataclass(frozen=True)
class EntropyGate(UncertaintyGate):
    """Label where the learner's class distribution is most spread: its entropy."""

    measure = staticmethod(entropy)
