"""Gates that read more than the learner's view: the oracle reads the expert's labels of the round's
states, the disagreement gate a reference head.

- ``oracle(quantile)``: the learner's-mistakes rule, a reference, not a method: it labels exactly
  the states where the learner is wrong (:class:`OracleGate`).
- :class:`DisagreementGate`: where a mapper's head for the seed and the current head act apart,
  MetaL DAgger's query rule; its benchmark methods (``disagree-<kind>``) are declared with the
  methods that need a mapper (:mod:`metadagger.evaluation.benchmark.methods`).

Each declares what it reads (``reads_expert``, ``reads_reference``), and the DAgger loop hands it
that in the round's :class:`~metadagger.imitation.gate_view.LearnerView`; the interface and the
other gates are in :mod:`metadagger.imitation.gates`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from metadagger.imitation.gate_view import LearnerView, Selection
from metadagger.imitation.gates import Gate, above_quantile, check_quantile


def learner_error(learner_actions: Tensor, expert_labels: Tensor) -> Tensor:
    """The learner's true error at each state [N]: 1 where its class differs from the expert's and 0
    elsewhere (class indices), or the squared distance between the two actions (action vectors)."""
    if expert_labels.dtype == torch.int64:
        return (learner_actions != expert_labels).double()
    return (learner_actions.double() - expert_labels.double()).square().sum(dim=1)


@dataclass(frozen=True)
class OracleGate(Gate):
    """The learner's-mistakes rule, a reference, not a method and not a ceiling (gates can beat
    it): it reads the expert's labels of the round's states
    and labels exactly the states where the learner is wrong (:func:`learner_error` above 0), those
    whose error is at least the ``quantile``-quantile of the round's positive errors. With class
    labels every wrong state has error 1, so every setting labels all of them; with action vectors
    the setting keeps the largest errors. It is charged for the states it labels alone."""

    setting: ClassVar[str] = "quantile"
    reads_expert: ClassVar[bool] = True
    quantile: float
    """In [0, 1): which share of the wrong states' errors is too small to ask about."""

    def __post_init__(self) -> None:
        check_quantile("OracleGate", self.quantile)

    def select(self, view: LearnerView) -> Selection:
        """The wrong states whose error is at least the ``quantile``-quantile of the round's positive errors."""
        errors = learner_error(view.actions, view.expert_labels)
        wrong = errors > 0
        if not wrong.any():
            return Selection(wrong, errors)
        threshold = torch.quantile(errors[wrong], self.quantile)
        return Selection(wrong & (errors >= threshold), errors)


def head_disagreement(view: LearnerView) -> Tensor:
    """Per state [N], how far apart the learner's head and the reference head act: the total
    variation distance between their class distributions (discrete, in [0, 1]), or the squared
    distance between their actions."""
    a, b = view.outputs_of(view.head), view.outputs_of(view.reference)
    if view.discrete:
        return 0.5 * (a.softmax(dim=1) - b.softmax(dim=1)).abs().sum(dim=1)
    return (a - b).square().sum(dim=1)


@dataclass(frozen=True)
class DisagreementGate(Gate):
    """Label where a reference head and the current head act apart: MetaL DAgger's query rule.

    The reference is a mapper's head for the seed (from its w_BC), made before any label is bought:
    where the head the pair seeds point to and the seed's current head disagree, the current head
    may be wrong. A state's score is :func:`head_disagreement`; the states strictly above the
    round's ``quantile`` are labelled (:func:`above_quantile`). Its control is the same rule with a
    constant head (mean-DA's, pi*'s) as the reference.
    """

    setting: ClassVar[str] = "quantile"
    reads_reference: ClassVar[bool] = True
    quantile: float
    """Scores strictly above this quantile of the round's scores are labelled, in [0, 1)."""

    def __post_init__(self) -> None:
        check_quantile("DisagreementGate", self.quantile)

    def select(self, view: LearnerView) -> Selection:
        """The states where the two heads act apart strictly above the round's ``quantile``."""
        scores = head_disagreement(view)
        return Selection(above_quantile(scores, self.quantile), scores)
