"""Query rules ("gates") of gated DAgger baselines: which visited states get an expert label.

Plain DAgger asks the expert to label every state the learner visited in a round. A gate asks
only about some of them (each label is one expert query) and is judged by the return it reaches
for the queries it spends. Every gate answers the same question through
:meth:`Gate.select`: given this round's trunk features and learner actions, and every state
labelled so far (:class:`Labelled`), a boolean mask of the states to label.

The gates:

- ``random(p)``: each state independently with probability ``p`` (the matched-budget control).
- ``ensemble(K, quantile)``: ``K`` bootstrap ridge heads fitted on the labelled states; a state's
  score is their disagreement there.
- ``safe(quantile)``: a ridge classifier of "the learner's action differs from the expert's" fitted
  on the labelled states; a state's score is its predicted mismatch.
- ``novelty(k, quantile)``: a state's score is its distance to the ``k``-th nearest labelled state.
- ``thrifty(rate)`` and ``conformal(alpha)``: ThriftyDAgger's and CRSAIL's rules, which set their
  thresholds from the run so far (:mod:`metadagger.imitation.memory_gates`).
- ``oracle(quantile)``, the learner's-mistakes rule (a reference), which reads the expert's labels
  of the round's states, and
  the disagreement gate, which reads two heads, MetaL DAgger's query rule
  (:mod:`metadagger.imitation.reading_gates`).

Each gate but the disagreement gate is declared once, with its label and default grid, in
:mod:`metadagger.imitation.gate_registry`; the disagreement gate's benchmark methods
(``disagree-<kind>``, one per mapper kind) are declared with the methods that need a mapper.

Score-based gates label a state when its score is strictly above the ``quantile``-quantile of
this round's scores (:func:`above_quantile`), so about a ``1 - quantile`` share of distinct
scores is labelled whatever the task's feature scale: one grid of settings serves every task.
The thrifty and conformal gates set their thresholds from the run so far instead, so their share
falls as the learner's states grow familiar; what they remember across the rounds of one run is
in a :class:`GateMemory` that the DAgger loop keeps. docs/benchmark.md says where the two differ
from the published methods.

Discrete tasks are told apart from continuous ones by the dtype of the labels: int64 class
indices or float32 action vectors. Gates take no number of classes: a head fitted on the
labelled states can only predict classes it has seen, so the one-hot width is the largest
label + 1.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import Tensor

from metadagger.errors import UserError


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


def _check_round(features: Tensor, learner_actions: Tensor, labelled: Labelled) -> None:
    if features.dtype != torch.float32 or features.ndim != 2 or len(features) == 0:
        raise UserError(
            f"a gate needs float32 features [N, F] with N >= 1, got {features.dtype} {tuple(features.shape)}"
        )
    if features.shape[1] != labelled.features.shape[1]:
        raise UserError(
            f"this round's features have width {features.shape[1]} but the labelled ones "
            f"{labelled.features.shape[1]}; use one trunk for both"
        )
    expected = (len(features),) + tuple(labelled.labels.shape[1:])
    if learner_actions.dtype != labelled.labels.dtype or tuple(learner_actions.shape) != expected:
        raise UserError(
            f"learner actions must be {labelled.labels.dtype} {expected} (one per state, laid out as the labels), "
            f"got {learner_actions.dtype} {tuple(learner_actions.shape)}"
        )


def check_quantile(owner: str, quantile: float) -> None:
    if not 0.0 <= quantile < 1.0:
        raise UserError(f"{owner}.quantile must be in [0, 1), got {quantile!r}")


def check_share(owner: str, value: float) -> None:
    """A setting that is a share strictly between 0 and 1 (``owner`` as ``Gate.field``)."""
    if not 0.0 < value < 1.0:
        raise UserError(f"{owner} must be in (0, 1), got {value!r}")


def check_count(owner: str, value: int, least: int) -> None:
    """An integer setting of at least ``least`` (``owner`` as ``Gate.field``)."""
    if not isinstance(value, int) or value < least:
        raise UserError(f"{owner} must be an integer >= {least}, got {value!r}")


def above_quantile(scores: Tensor, quantile: float) -> Tensor:
    """The states whose score is strictly above the ``quantile``-quantile of ``scores``.

    The quantile interpolates linearly between order statistics (:func:`torch.quantile`), so with
    N distinct scores about ``(1 - quantile) * N`` states pass (the lowest score never does). A
    score equal to the threshold does not pass: ties at the threshold are all left out, and a
    round whose scores are all equal labels nothing.

    Args:
        scores: one score per state, [N].
        quantile: in [0, 1).

    Returns:
        A bool mask [N].
    """
    threshold = torch.quantile(scores.double(), quantile)
    return scores.double() > threshold


def ridge_weights(features: Tensor, targets: Tensor, ridge: float) -> Tensor:
    """Weights [F + 1, T] (bias last) of a ridge regression of ``targets`` [M, T] on ``features`` [M, F]."""
    x = with_bias(features)
    gram = x.T @ x
    # the penalty scales with the features' mean energy, so one ridge value suits every trunk
    gram.diagonal().add_(ridge * gram.diagonal().mean())
    return torch.linalg.solve(gram, x.T @ targets.double())


def with_bias(features: Tensor) -> Tensor:
    x = features.double()
    return torch.cat([x, torch.ones(len(x), 1, dtype=x.dtype)], dim=1)


def check_ridge(owner: str, ridge: float) -> None:
    if not ridge > 0:
        raise UserError(f"{owner}.ridge must be > 0, got {ridge!r}")


@dataclass(frozen=True)
class Selection:
    """A gate's choice in one round: the states to label, and each state's score where the gate has one."""

    mask: Tensor
    """Bool [N]: True for a state to label."""
    scores: Tensor | None = None
    """The score [N] the choice was made on (higher: more worth a query); None for a gate without one."""


@dataclass(frozen=True)
class HeadPair:
    """The two heads a :class:`DisagreementGate` compares, flat (weight rows, then bias)."""

    current: Tensor
    """The head whose rollout the round gates."""
    reference: Tensor
    """The head it is compared with: a mapper's for the seed (the MetaL rule), or a constant one (its twin)."""
    outputs: int
    """The heads' outputs: classes (discrete) or the action's length."""

    def __post_init__(self) -> None:
        if self.current.shape != self.reference.shape or self.current.ndim != 1:
            raise UserError(
                f"HeadPair heads must be flat and of one length, got {tuple(self.current.shape)} and "
                f"{tuple(self.reference.shape)}; compare heads of one policy"
            )


class Gate(ABC):
    """A query rule of gated DAgger: which of a round's visited states get an expert label.

    A gate of your own subclasses this (or :class:`ScoreGate`), names the field its sweep sets in
    ``setting``, implements ``_select`` and is declared once in
    :mod:`metadagger.imitation.gate_registry` (docs/benchmark.md, "Adding a gate").
    """

    setting: ClassVar[str]
    """The field set by the sweep value of :func:`~metadagger.imitation.gate_registry.make_gate`."""
    reads_expert: ClassVar[bool] = False
    """Whether the gate reads the expert's labels of the round's states: only a reference may (the oracle)."""
    reads_heads: ClassVar[bool] = False
    """Whether the gate reads the current head and a reference head (:class:`HeadPair`)."""

    def choose(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        *,
        generator: torch.Generator,
        memory: GateMemory | None = None,
        expert_labels: Tensor | None = None,
        heads: HeadPair | None = None,
    ) -> Selection:
        """As :meth:`select`, with the scores the choice was made on; ``expert_labels`` (this round's
        states' labels, laid out as ``labelled.labels``) is read by a reference gate alone, ``heads``
        by a gate that compares two heads."""
        _check_round(features, learner_actions, labelled)
        memory = GateMemory() if memory is None else memory
        chosen = self._choose(features, learner_actions, labelled, generator, memory, expert_labels, heads)
        return chosen if isinstance(chosen, Selection) else Selection(chosen)

    def select(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        *,
        generator: torch.Generator,
        memory: GateMemory | None = None,
    ) -> Tensor:
        """The states of this round to label.

        Args:
            features: trunk features of this round's visited states, float32 [N, F].
            learner_actions: the learner's actions there, int64 [N] or float32 [N, d] as the labels.
            labelled: every state labelled so far, for gates that fit on it.
            generator: the source of all randomness.
            memory: the run's earlier rounds, for gates that remember (updated in place); None is
                a run's first round with nothing remembered.

        Returns:
            A bool mask [N]: True for a state to label.
        """
        return self.choose(features, learner_actions, labelled, generator=generator, memory=memory).mask

    def _choose(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        generator: torch.Generator,
        memory: GateMemory,
        expert_labels: Tensor | None,
        heads: HeadPair | None,
    ) -> Tensor | Selection:
        """The choice from every input a round may give; a gate that reads the expert's labels or two
        heads overrides this, every other gate :meth:`_select`."""
        return self._select(features, learner_actions, labelled, generator, memory)

    def _select(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        generator: torch.Generator,
        memory: GateMemory,
    ) -> Tensor | Selection:
        """The states to label: a bool mask [N], or a :class:`Selection` with the scores behind it."""
        raise NotImplementedError(f"{type(self).__name__} must implement _select (docs/benchmark.md, 'Adding a gate')")


@dataclass(frozen=True)
class RandomGate(Gate):
    """Label each state independently with probability ``p``: the matched-budget control."""

    setting: ClassVar[str] = "p"
    p: float
    """Probability of labelling a state, in [0, 1]."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.p <= 1.0:
            raise UserError(f"RandomGate.p must be in [0, 1], got {self.p!r}")

    def _select(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        generator: torch.Generator,
        memory: GateMemory,
    ) -> Tensor:
        return torch.rand(len(features), generator=generator) < self.p


class ScoreGate(Gate):
    """A gate that scores every state and labels those strictly above this round's quantile."""

    setting: ClassVar[str] = "quantile"
    quantile: float

    def _select(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        generator: torch.Generator,
        memory: GateMemory,
    ) -> Tensor:
        scores = self.scores(features, learner_actions, labelled, generator)
        return Selection(above_quantile(scores, self.quantile), scores)

    @abstractmethod
    def scores(
        self, features: Tensor, learner_actions: Tensor, labelled: Labelled, generator: torch.Generator
    ) -> Tensor:
        """One score per state [N]; higher means more worth an expert query."""


@dataclass(frozen=True)
class EnsembleGate(ScoreGate):
    """Label where ``K`` bootstrap ridge heads fitted on the labelled states disagree.

    Each head is a closed-form ridge regression on the features (one F x F solve) of one-hot class
    targets or of the action vectors, fitted on the labelled rows resampled with replacement.
    Disagreement is the variance of the heads' outputs summed over output dimensions (continuous),
    or the entropy of the heads' argmax votes (discrete). K votes take few distinct entropies, and
    far from the labelled states the heads often agree on an extrapolated class, so equal
    entropies are ordered by the output variance of the one-hot heads: the discrete score is the
    rank of the pair (vote entropy, variance), and only states equal in both tie.
    """

    quantile: float
    """Scores strictly above this quantile of the round's scores are labelled, in [0, 1)."""
    K: int = 5
    """Bootstrap heads, >= 2."""
    ridge: float = 1e-3
    """Ridge penalty relative to the features' mean energy, > 0."""

    def __post_init__(self) -> None:
        check_quantile("EnsembleGate", self.quantile)
        check_count("EnsembleGate.K", self.K, 2)
        check_ridge("EnsembleGate", self.ridge)

    def scores(
        self, features: Tensor, learner_actions: Tensor, labelled: Labelled, generator: torch.Generator
    ) -> Tensor:
        """Disagreement of the ``K`` bootstrap heads at each state [N]."""
        outputs = bootstrap_outputs(features, labelled, self.K, self.ridge, generator)
        variance = outputs.var(dim=0, unbiased=False).sum(dim=1)
        if not labelled.discrete:
            return variance
        votes = torch.nn.functional.one_hot(outputs.argmax(dim=2), outputs.shape[2]).double().mean(dim=0)
        entropy = -(votes * votes.clamp_min(1e-12).log()).sum(dim=1)
        # rank by (entropy, variance): unique(dim=0) sorts rows lexicographically, equal pairs share a rank
        return torch.unique(torch.stack([entropy, variance], dim=1), dim=0, return_inverse=True)[1].double()


def bootstrap_outputs(
    features: Tensor, labelled: Labelled, heads: int, ridge: float, generator: torch.Generator
) -> Tensor:
    """The outputs [K, N, T] at ``features`` of ``heads`` ridge heads, each fitted on the labelled
    rows resampled with replacement, of one-hot class targets or of the action vectors."""
    targets = labelled.labels
    if labelled.discrete:
        targets = torch.nn.functional.one_hot(targets, int(targets.max()) + 1)
    m, x = len(targets), with_bias(features)
    outputs = []
    for _ in range(heads):
        rows = torch.randint(m, (m,), generator=generator)
        outputs.append(x @ ridge_weights(labelled.features[rows], targets[rows], ridge))
    return torch.stack(outputs)


@dataclass(frozen=True)
class SafeGate(ScoreGate):
    """Label where a classifier predicts the learner's action differs from the expert's.

    The classifier is a ridge regression on the features of 0/1 mismatch targets of the labelled
    states (its output estimates the probability of a mismatch; only its ranking matters). A
    labelled state is a mismatch when the learner's class differs from the label (discrete), or
    when the L2 distance between learner action and label is strictly above the median distance
    over the labelled states (continuous). When the labelled states hold only one kind of target
    (e.g. only the demonstration, where the learner's action is the label) there is nothing to
    learn from, and every state is labelled, as plain DAgger would.
    """

    quantile: float
    """Scores strictly above this quantile of the round's scores are labelled, in [0, 1)."""
    ridge: float = 0.1
    """Ridge penalty relative to the features' mean energy, > 0 (stronger than the ensemble's:
    mismatch targets are noisy, and the classifier should smooth them rather than fit them)."""

    def __post_init__(self) -> None:
        check_quantile("SafeGate", self.quantile)
        check_ridge("SafeGate", self.ridge)

    def _select(
        self,
        features: Tensor,
        learner_actions: Tensor,
        labelled: Labelled,
        generator: torch.Generator,
        memory: GateMemory,
    ) -> Tensor:
        if len(_mismatch(labelled).unique()) < 2:
            return torch.ones(len(features), dtype=torch.bool)
        return super()._select(features, learner_actions, labelled, generator, memory)

    def scores(
        self, features: Tensor, learner_actions: Tensor, labelled: Labelled, generator: torch.Generator
    ) -> Tensor:
        """Predicted mismatch of the learner's action at each state [N]."""
        weights = ridge_weights(labelled.features, _mismatch(labelled).double().unsqueeze(1), self.ridge)
        return (with_bias(features) @ weights).squeeze(1)


def _mismatch(labelled: Labelled) -> Tensor:
    """Whether the learner's action at each labelled state counts as differing from the label [M]."""
    if labelled.discrete:
        return labelled.learner_actions != labelled.labels
    distance = (labelled.learner_actions - labelled.labels).norm(dim=1)
    return distance > distance.median()


@dataclass(frozen=True)
class NoveltyGate(ScoreGate):
    """Label states far from everything labelled: score = Euclidean distance to the ``k``-th
    nearest labelled feature vector."""

    quantile: float
    """Scores strictly above this quantile of the round's scores are labelled, in [0, 1)."""
    k: int = 1
    """Which nearest labelled neighbour measures the distance, >= 1 (at most the labelled count)."""

    def __post_init__(self) -> None:
        check_quantile("NoveltyGate", self.quantile)
        check_count("NoveltyGate.k", self.k, 1)

    def scores(
        self, features: Tensor, learner_actions: Tensor, labelled: Labelled, generator: torch.Generator
    ) -> Tensor:
        """Distance of each state to its ``k``-th nearest labelled state [N]."""
        return neighbour_distance(features, labelled, self.k, "NoveltyGate")


def neighbour_distance(features: Tensor, labelled: Labelled, k: int, owner: str) -> Tensor:
    """Euclidean distance [N] of each state to its ``k``-th nearest labelled state."""
    if k > len(labelled.features):
        raise UserError(f"{owner}.k = {k} needs at least {k} labelled states, got {len(labelled.features)}; lower k")
    return torch.cdist(features, labelled.features).kthvalue(k, dim=1).values
