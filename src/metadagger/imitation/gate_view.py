"""What a gate is handed for one DAgger round (:class:`LearnerView`) and what it hands back (:class:`Selection`).

A gate sees the round the way the learner lived it: the trunk features of the states its last
rollout visited, one episode in step order (with lanes or without: a lane hands its chain each
episode whole); its outputs there (class logits for a classification head, the action vectors
otherwise) and the actions it took; its current head; every state labelled so far
(:class:`Labelled`); the run's generator and the gate's :class:`GateMemory`. Two things only a
gate that declares them receives: a reference head (``reads_reference``, MetaL DAgger's
disagreement rule) and the expert's labels of the round's states (``reads_expert``, the oracle,
a reference). docs/benchmark.md ("What a gate sees") lists every field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from metadagger.errors import UserError
from metadagger.imitation.head_fits import head_outputs


@dataclass(frozen=True)
class Labelled:
    """Every state labelled so far: the demonstration's and earlier rounds' labelled states.

    On the demonstration's states the learner action is the expert's own label.
    """

    features: Tensor
    """Trunk features, float32 [M, F]."""
    labels: Tensor
    """Expert labels: int64 class indices [M] or float32 actions [M, d]."""
    learner_actions: Tensor
    """The learner's actions at the same states, laid out as ``labels``."""

    def __post_init__(self) -> None:
        if self.features.dtype != torch.float32 or self.features.ndim != 2 or len(self.features) == 0:
            raise UserError(
                f"Labelled.features must be float32 [M, F] with M >= 1, got {self.features.dtype} "
                f"{tuple(self.features.shape)}"
            )
        m = len(self.features)
        if self.labels.dtype == torch.int64:
            if tuple(self.labels.shape) != (m,):
                raise UserError(
                    f"Labelled.labels of class indices must be [M] = ({m},), got {tuple(self.labels.shape)}"
                )
        elif self.labels.dtype != torch.float32 or self.labels.ndim != 2 or len(self.labels) != m:
            raise UserError(
                f"Labelled.labels must be int64 [M] or float32 [M, d] with M = {m}, got {self.labels.dtype} "
                f"{tuple(self.labels.shape)}"
            )
        if self.learner_actions.dtype != self.labels.dtype or self.learner_actions.shape != self.labels.shape:
            raise UserError(
                f"Labelled.learner_actions must be laid out as the labels ({self.labels.dtype} "
                f"{tuple(self.labels.shape)}), "
                f"got {self.learner_actions.dtype} {tuple(self.learner_actions.shape)}"
            )

    @property
    def discrete(self) -> bool:
        """Whether the labels are class indices."""
        return self.labels.dtype == torch.int64


@dataclass(frozen=True)
class Episode:
    """A finished episode of the run: its visited states' trunk features and its outcome."""

    features: Tensor
    """Trunk features of every visited state, float32 [T, F]."""
    succeeded: bool
    """The task's success rule at its end."""


@dataclass
class GateMemory:
    """What the gates of one DAgger run may know of its earlier rounds (one per run).

    The DAgger loop adds each episode once its states have been gated (the demonstration first);
    a gate keeps its own thresholds and estimates in ``notes``, under its name.
    """

    episodes: list[Episode] = field(default_factory=list)
    """The finished episodes before this round's rollout, in order."""
    notes: dict[str, Any] = field(default_factory=dict)
    """Each gate's own record across rounds."""


@dataclass(frozen=True)
class LearnerView:
    """One DAgger round as a gate sees it: the learner's last rollout, its head and what is labelled.

    Built by the DAgger loop for every round (:func:`~metadagger.metal_dagger.method.dagger_rounds`);
    a test or a notebook builds one with :meth:`of`.
    """

    features: Tensor
    """Trunk features of the round's N visited states, one episode in step order, float32 [N, F]:
    the ones the learner computed to act on them."""
    outputs: Tensor
    """The learner's outputs there, float32: class logits [N, C] for a classification head, action
    vectors [N, d] otherwise."""
    actions: Tensor
    """The actions it took there: int64 classes [N] (the logits' argmax) or float32 vectors [N, d],
    laid out as ``labelled.labels``."""
    head: Tensor
    """Its current head, the one the rollout acted with: flat float32 [C * F + C] (weight rows,
    then biases, as :func:`~metadagger.imitation.head_fits.head_outputs` reads it)."""
    labelled: Labelled
    """Every state labelled so far (the demonstration first)."""
    generator: torch.Generator
    """The source of all the gate's randomness (seeded by the env seed)."""
    memory: GateMemory
    """The run's earlier rounds, and the gate's own notes (updated in place)."""
    reference: Tensor | None = None
    """A reference head laid out as ``head`` (a mapper's for the seed, or a constant one); only for
    a gate that declares ``reads_reference``."""
    expert_labels: Tensor | None = None
    """The expert's labels of the round's states, laid out as ``actions``; only for a reference gate
    that declares ``reads_expert`` (the oracle)."""

    def __post_init__(self) -> None:
        n = len(self.features)
        if self.features.dtype != torch.float32 or self.features.ndim != 2 or n == 0:
            raise UserError(
                f"a gate needs float32 features [N, F] with N >= 1, got {self.features.dtype} "
                f"{tuple(self.features.shape)}"
            )
        width = self.features.shape[1]
        if width != self.labelled.features.shape[1]:
            raise UserError(
                f"this round's features have width {width} but the labelled ones "
                f"{self.labelled.features.shape[1]}; use one trunk for both"
            )
        labels = self.labelled.labels
        expected = (n,) + tuple(labels.shape[1:])
        if self.actions.dtype != labels.dtype or tuple(self.actions.shape) != expected:
            raise UserError(
                f"learner actions must be {labels.dtype} {expected} (one per state, laid out as the labels), "
                f"got {self.actions.dtype} {tuple(self.actions.shape)}"
            )
        if self.outputs.dtype != torch.float32 or self.outputs.ndim != 2 or len(self.outputs) != n:
            raise UserError(
                f"learner outputs must be float32 [N, C] with N = {n}, got {self.outputs.dtype} "
                f"{tuple(self.outputs.shape)}"
            )
        size = self.outputs.shape[1] * (width + 1)
        if self.head.dtype != torch.float32 or tuple(self.head.shape) != (size,):
            raise UserError(
                f"the learner's head must be flat float32 [{size}] (outputs x (features + 1)), got "
                f"{self.head.dtype} {tuple(self.head.shape)}"
            )
        if self.reference is not None and self.reference.shape != self.head.shape:
            raise UserError(
                f"the reference head must be laid out as the learner's ({size},), got {tuple(self.reference.shape)}; "
                "compare heads of one policy"
            )
        if self.expert_labels is not None and (
            self.expert_labels.dtype != self.actions.dtype or self.expert_labels.shape != self.actions.shape
        ):
            raise UserError(
                f"the expert's labels must be laid out as the learner's actions ({self.actions.dtype} "
                f"{tuple(self.actions.shape)}), got {self.expert_labels.dtype} {tuple(self.expert_labels.shape)}"
            )

    @classmethod
    def of(
        cls,
        features: Tensor,
        head: Tensor,
        labelled: Labelled,
        *,
        generator: torch.Generator | None = None,
        memory: GateMemory | None = None,
        actions: Tensor | None = None,
        reference: Tensor | None = None,
        expert_labels: Tensor | None = None,
    ) -> LearnerView:
        """The view of a learner acting with ``head`` on ``features``: its outputs computed from the
        head, its actions their argmax (classes, where ``labelled`` holds class labels) or the
        outputs themselves, unless ``actions`` gives them."""
        if head.dtype != torch.float32 or head.ndim != 1:
            raise UserError(f"the learner's head must be flat float32, got {head.dtype} {tuple(head.shape)}")
        outputs = head.numel() // (features.shape[1] + 1)
        logits = head_outputs(head, features, outputs)
        if actions is None:
            actions = logits.argmax(dim=1) if labelled.discrete else logits.clone()
        return cls(
            features=features,
            outputs=logits,
            actions=actions,
            head=head,
            labelled=labelled,
            generator=torch.Generator() if generator is None else generator,
            memory=GateMemory() if memory is None else memory,
            reference=reference,
            expert_labels=expert_labels,
        )

    @property
    def discrete(self) -> bool:
        """Whether the learner's outputs are class logits (its actions class indices)."""
        return self.labelled.discrete

    def probabilities(self) -> Tensor:
        """The learner's class distribution at each state, softmax of its logits, float64 [N, C];
        a :class:`UserError` for a head of action vectors."""
        if not self.discrete:
            raise UserError(
                "the learner acts with action vectors here, so it has no class distribution; use a gate that "
                "reads its outputs or features instead"
            )
        return self.outputs.double().softmax(dim=1)

    def outputs_of(self, head: Tensor) -> Tensor:
        """Another flat head's outputs on the round's states, laid out as :attr:`outputs`, float64."""
        return head_outputs(head.double(), self.features.double(), self.outputs.shape[1])


@dataclass(frozen=True)
class Selection:
    """A gate's choice in one round: the states to label, and each state's score where the gate has one."""

    mask: Tensor
    """Bool [N]: True for a state to label."""
    scores: Tensor | None = None
    """The score [N] the choice was made on (higher: more worth a query); None for a gate without one."""
