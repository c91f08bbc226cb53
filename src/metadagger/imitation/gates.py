"""Query rules ("gates") of gated DAgger baselines: which visited states get an expert label.

Plain DAgger asks the expert to label every state the learner visited in a round. A gate asks
only about some of them (each label is one expert query) and is judged by the return it reaches
for the queries it spends. Every gate answers the same question through :meth:`Gate.choose`:
given the round as the learner lived it (:class:`~metadagger.imitation.gate_view.LearnerView`:
the trunk features of the states of its one rollout, in step order, its outputs and actions
there, its head, every state labelled so far), a boolean mask of the states to label. A gate
implements :meth:`Gate.select`; :meth:`Gate.choose` checks what it returns.

The gates:

- ``random(p)``: each state independently with probability ``p`` (the matched-budget control).
- ``ensemble(K, quantile)``: ``K`` bootstrap ridge heads fitted on the labelled states; a state's
  score is their disagreement there.
- ``safe(quantile)``: a ridge classifier of "the learner's action differs from the expert's" fitted
  on the labelled states; a state's score is its predicted mismatch.
- ``novelty(k, quantile)``: a state's score is its distance to the ``k``-th nearest labelled state.
- ``least-confidence``, ``margin`` and ``entropy`` (quantile): uncertainty sampling on the
  learner's own class distribution (:mod:`metadagger.imitation.uncertainty_gates`).
- ``thrifty(rate)`` and ``conformal(alpha)``: ThriftyDAgger's and CRSAIL's rules, which set their
  thresholds from the run so far (:mod:`metadagger.imitation.memory_gates`).
- ``oracle(quantile)``, the learner's-mistakes rule (a reference), which reads the expert's labels
  of the round's states, and
  the disagreement gate, which reads a reference head, MetaL DAgger's query rule
  (:mod:`metadagger.imitation.reading_gates`).

Each gate but the disagreement gate is declared once, with its label and default grid, in
:mod:`metadagger.imitation.gate_registry`; the disagreement gate's benchmark methods
(``disagree-<kind>``, one per mapper kind) are declared with the methods that need a mapper.

Score-based gates label a state when its score is strictly above the ``quantile``-quantile of
this round's scores (:func:`above_quantile`), so about a ``1 - quantile`` share of distinct
scores is labelled whatever the task's feature scale: one grid of settings serves every task.
The thrifty and conformal gates set their thresholds from the run so far instead, so their share
falls as the learner's states grow familiar; what they remember across the rounds of one run is
in a :class:`~metadagger.imitation.gate_view.GateMemory` that the DAgger loop keeps.
docs/benchmark.md says where the two differ from the published methods.

Discrete tasks are told apart from continuous ones by the dtype of the labels: int64 class
indices or float32 action vectors. Gates take no number of classes: a head fitted on the
labelled states can only predict classes it has seen, so the one-hot width is the largest
label + 1.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from metadagger.errors import UserError
from metadagger.imitation.gate_view import Labelled, LearnerView, Selection


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


class Gate(ABC):
    """A query rule of gated DAgger: which of a round's visited states get an expert label.

    A gate of your own subclasses this (or :class:`ScoreGate`), names the field its sweep sets in
    ``setting``, implements :meth:`select` on the round's :class:`~metadagger.imitation.gate_view.LearnerView`
    and is declared once in :mod:`metadagger.imitation.gate_registry` (docs/benchmark.md, "Adding a gate").
    Callers ask :meth:`choose`, which checks the view against what the gate reads and what
    :meth:`select` returns against the round's states.
    """

    setting: ClassVar[str]
    """The field set by the sweep value of :func:`~metadagger.imitation.gate_registry.make_gate`."""
    reads_expert: ClassVar[bool] = False
    """Whether the gate reads the expert's labels of the round's states: only a reference may (the oracle)."""
    reads_reference: ClassVar[bool] = False
    """Whether the gate reads a reference head beside the learner's (MetaL DAgger's disagreement rule)."""
    needs_classes: ClassVar[bool] = False
    """Whether the gate reads the learner's class distribution, so serves classification heads alone."""

    def choose(self, view: LearnerView) -> Selection:
        """The states of this round to label, with the scores the choice was made on: :meth:`select`'s
        answer, checked and wrapped in a :class:`Selection`.

        Args:
            view: the round as the learner lived it; it must carry what the gate declares it reads.

        Returns:
            A :class:`Selection`: a bool mask [N] (True: label the state) and the scores, where the gate has some.
        """
        name = type(self).__name__
        if self.reads_expert and view.expert_labels is None:
            raise UserError(f"{name} reads the expert's labels of the round's states: build the view with them")
        if self.reads_reference and view.reference is None:
            raise UserError(f"{name} compares the learner's head with a reference head: build the view with reference")
        if self.needs_classes and not view.discrete:
            raise UserError(f"{name} reads the learner's class distribution, but it acts with action vectors here")
        chosen = self.select(view)
        chosen = chosen if isinstance(chosen, Selection) else Selection(chosen)
        n = len(view.features)
        if chosen.mask.dtype != torch.bool or tuple(chosen.mask.shape) != (n,):
            raise UserError(f"{name} must choose a bool mask [{n}], got {chosen.mask.dtype} {tuple(chosen.mask.shape)}")
        if chosen.scores is not None and tuple(chosen.scores.shape) != (n,):
            raise UserError(f"{name}'s scores must be one per state [{n}], got {tuple(chosen.scores.shape)}")
        return chosen

    @abstractmethod
    def select(self, view: LearnerView) -> Tensor | Selection:
        """The states of one episode to label (``view.features``' rows, in step order): a bool mask [N],
        or a :class:`Selection` with the scores behind it. A gate implements this; callers ask :meth:`choose`."""


@dataclass(frozen=True)
class RandomGate(Gate):
    """Label each state independently with probability ``p``: the matched-budget control."""

    setting: ClassVar[str] = "p"
    p: float
    """Probability of labelling a state, in [0, 1]."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.p <= 1.0:
            raise UserError(f"RandomGate.p must be in [0, 1], got {self.p!r}")

    def select(self, view: LearnerView) -> Tensor:
        """Each state independently with probability ``p``."""
        return torch.rand(len(view.features), generator=view.generator) < self.p


class ScoreGate(Gate):
    """A gate that scores every state and labels those strictly above this round's quantile."""

    setting: ClassVar[str] = "quantile"
    quantile: float

    def select(self, view: LearnerView) -> Selection:
        """The states scored strictly above the ``quantile``-quantile of the round's scores."""
        scores = self.scores(view)
        return Selection(above_quantile(scores, self.quantile), scores)

    @abstractmethod
    def scores(self, view: LearnerView) -> Tensor:
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

    def scores(self, view: LearnerView) -> Tensor:
        """Disagreement of the ``K`` bootstrap heads at each state [N]."""
        outputs = bootstrap_outputs(view.features, view.labelled, self.K, self.ridge, view.generator)
        variance = outputs.var(dim=0, unbiased=False).sum(dim=1)
        if not view.discrete:
            return variance
        votes = torch.nn.functional.one_hot(outputs.argmax(dim=2), outputs.shape[2]).double().mean(dim=0)
        entropy = -torch.special.xlogy(votes, votes).sum(dim=1)  # libm's log: Tensor.log's bits depend on the CPU
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

    def select(self, view: LearnerView) -> Tensor | Selection:
        """The score gate's choice; every state while the labelled states hold one kind of target only."""
        if len(_mismatch(view.labelled).unique()) < 2:
            return torch.ones(len(view.features), dtype=torch.bool)
        return super().select(view)

    def scores(self, view: LearnerView) -> Tensor:
        """Predicted mismatch of the learner's action at each state [N]."""
        weights = ridge_weights(view.labelled.features, _mismatch(view.labelled).double().unsqueeze(1), self.ridge)
        return (with_bias(view.features) @ weights).squeeze(1)


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

    def scores(self, view: LearnerView) -> Tensor:
        """Distance of each state to its ``k``-th nearest labelled state [N]."""
        return neighbour_distance(view.features, view.labelled, self.k, "NoveltyGate")


def neighbour_distance(features: Tensor, labelled: Labelled, k: int, owner: str) -> Tensor:
    """Euclidean distance [N] of each state to its ``k``-th nearest labelled state."""
    if k > len(labelled.features):
        raise UserError(f"{owner}.k = {k} needs at least {k} labelled states, got {len(labelled.features)}; lower k")
    # each distance summed and rooted pair by pair (the CPU's correctly rounded root): cdist's
    # matrix-product form roots with MKL's vector math, whose bits depend on the CPU
    distances = torch.cdist(features, labelled.features, compute_mode="donot_use_mm_for_euclid_dist")
    return distances.kthvalue(k, dim=1).values
