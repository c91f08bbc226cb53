"""LazyDAgger's query rule (Hoque et al., CASE 2021): SafeDAgger's mismatch score, switched with hysteresis.

SafeDAgger hands a state to the expert whenever a classifier predicts that the learner's action
there differs from the expert's, so the expert is called in and dismissed at every crossing of one
threshold. LazyDAgger keeps the classifier and splits the threshold in two: the expert takes over
when the score rises above a high threshold, and keeps control, labelling every step, until the
score falls below a lower one. The labelled steps come in fewer, longer runs: fewer context
switches for the expert.

Here the score is :meth:`metadagger.imitation.gates.SafeGate.scores` (a ridge classifier of
"learner differs from expert" fitted on the labelled states), and both thresholds are quantiles of
the round's scores, as for metadagger's score gates: the high one is the ``quantile``-quantile (the
sweep's setting), the low one the ``low``-quantile. The DAgger round hands the gate one finished
rollout, in step order, and the switching runs along it afterwards (README.md says how that differs
from the published method).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from metadagger.errors import UserError
from metadagger.imitation.gate_view import LearnerView, Selection
from metadagger.imitation.gates import Gate, SafeGate


def _check_number(owner: str, value: object, low: float, high: float, *, high_included: bool, range_: str) -> None:
    """``value`` a real number in ``[low, high]`` (``[low, high)`` without ``high_included``), else a
    :class:`UserError` naming ``owner`` (``Gate.field``), the allowed ``range_`` and the value."""
    number = isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value)
    if not (number and low <= value and (value <= high if high_included else value < high)):
        raise UserError(f"{owner} must be a number in {range_}, got {value!r}")


def hysteresis(scores: Tensor, high: float, low: float) -> Tensor:
    """The steps the expert drives when it takes over above ``high`` and hands back below ``low``.

    Walking the steps in order: while the learner drives, a step scored strictly above ``high`` is
    a takeover, and that step is the expert's; while the expert drives, it keeps every step until
    one scored strictly below ``low``, which is the learner's again. With ``low <= high`` every step
    above ``high`` is the expert's, so the result holds the plain threshold's steps
    (``scores > high``), joined into at most as many runs.

    Args:
        scores: one score per step of one episode, in step order, [N].
        high: the takeover threshold.
        low: the hand-back threshold, at most ``high``.

    Returns:
        A bool mask [N]: True for a step the expert drives (and labels).
    """
    if low > high:
        raise UserError(f"the hand-back threshold {low!r} must not be above the takeover threshold {high!r}")
    expert = False
    driven = []
    for score in scores.double().tolist():
        expert = not score < low if expert else score > high
        driven.append(expert)
    return torch.tensor(driven, dtype=torch.bool)


@dataclass(frozen=True)
class LazyGate(Gate):
    """LazyDAgger: the expert takes over where SafeDAgger's mismatch score is high, and keeps
    control until it is low again.

    Both thresholds are quantiles of this round's scores: a takeover above the ``quantile``-quantile,
    a hand-back below the ``low``-quantile (default: half of ``quantile``). ``low = quantile`` is
    the safe gate but for a step scored exactly at the threshold, which stays with an expert in
    control; ``low = 0`` keeps the expert in control to the end of the episode after the first
    takeover. While the labelled states hold one kind of
    mismatch target only (round 1, where they are the demonstration's), there is no classifier to
    fit, and every state is labelled, as the safe gate does.
    """

    setting: ClassVar[str] = "quantile"
    quantile: float
    """The takeover threshold: steps scored strictly above this quantile of the round's scores take over, in [0, 1)."""
    low: float | None = None
    """The hand-back threshold: the expert hands back at a step scored strictly below this quantile
    of the round's scores, in [0, quantile]; None: half of ``quantile``."""
    ridge: float = 0.1
    """The mismatch classifier's ridge penalty, relative to the features' mean energy, > 0 (the safe gate's)."""

    def __post_init__(self) -> None:
        _check_number("LazyGate.quantile", self.quantile, 0.0, 1.0, high_included=False, range_="[0, 1)")
        if self.low is not None:
            within = f"[0, quantile] = [0, {self.quantile:g}]"
            _check_number("LazyGate.low", self.low, 0.0, self.quantile, high_included=True, range_=within)
        if not (isinstance(self.ridge, (int, float)) and not isinstance(self.ridge, bool) and self.ridge > 0):
            raise UserError(f"LazyGate.ridge must be a number > 0, got {self.ridge!r}")

    @property
    def hand_back(self) -> float:
        """The quantile of the round's scores below which the expert hands back: ``low``, or half of ``quantile``."""
        return self.quantile / 2 if self.low is None else float(self.low)

    def select(self, view: LearnerView) -> Selection:
        """The steps the expert drives along the round's episode, with the safe gate's scores."""
        plain = SafeGate(self.quantile, ridge=self.ridge).choose(view)
        if plain.scores is None:  # no classifier to fit yet: the safe gate labels every state
            return plain
        scores = plain.scores.double()
        high = float(torch.quantile(scores, self.quantile))
        low = float(torch.quantile(scores, self.hand_back))
        return Selection(hysteresis(scores, high, low), plain.scores)
