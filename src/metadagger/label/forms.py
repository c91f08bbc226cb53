"""How a person labels a task's states: named classes for a discrete task, a slider per dimension for a vector.

A task declares its form with a method ``person_labels(self) -> LabelForm``; a task that declares
nothing gets :func:`default_form` of its learner action space. The packaged tasks' forms are kept
here (:func:`label_form`) rather than in their classes: a task's code fingerprint covers its
package's source files, and a new line there would mark every run made with it stale.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import Task
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask

#: The most characters of a refused value a refusal shows: a request may hold any value, a refusal stays one line.
SHOWN = 80


class Refused(Exception):
    """A label or request the page must refuse, with one line saying why; ``status`` is its HTTP code."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


def shown(value: Any) -> str:
    """``repr(value)`` for a refusal, cut as :func:`clipped` cuts it."""
    return clipped(repr(value))


def clipped(text: str) -> str:
    """``text`` cut to :data:`SHOWN` characters, with its whole length named where it is cut."""
    return text if len(text) <= SHOWN else f"{text[: SHOWN - 3]}... ({len(text)} characters)"


@dataclass(frozen=True)
class Slider:
    """One dimension of an action vector, set by a slider (or typed) between ``low`` and ``high``."""

    name: str
    low: float
    high: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise UserError(f"slider {self.name!r} needs finite bounds low < high, got [{self.low}, {self.high}]")


@dataclass(frozen=True)
class LabelForm:
    """What the page offers a person for a state: ``classes`` (a discrete task, one name per class index,
    in the order shown: left to right) or ``sliders`` (an action vector, one per dimension).

    ``asks`` says in a sentence or two what a label is (the page shows it above the form; empty: a
    line of the form's kind); ``marks`` names classes a person looks for, as ``(index, word)``
    pairs shown under their buttons (CarRacing's two classes nearest straight).
    """

    classes: tuple[str, ...] = ()
    sliders: tuple[Slider, ...] = field(default=())
    asks: str = ""
    marks: tuple[tuple[int, str], ...] = ()

    def __post_init__(self) -> None:
        if bool(self.classes) == bool(self.sliders):
            raise UserError(
                f"a label form has either classes or sliders, got {len(self.classes)} classes and "
                f"{len(self.sliders)} sliders"
            )
        wrong = [index for index, _ in self.marks if not 0 <= index < len(self.classes)]
        if wrong:
            raise UserError(
                f"label form marks {wrong} name no class: a mark is (class index, word) with an index in "
                f"[0, {len(self.classes) - 1}], and only classes take marks"
            )

    @property
    def size(self) -> int:
        """Classes of a discrete task, dimensions of a vector."""
        return len(self.classes) or len(self.sliders)

    def check(self, value: Any) -> int | list[float]:
        """``value`` as the ledger keeps it (a class index, or a vector of float32 values as floats);
        one that is out of range or of the wrong kind is :class:`Refused`."""
        if self.classes:
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < len(self.classes):
                raise Refused(f"label {shown(value)} refused: expected a class index in [0, {len(self.classes) - 1}]")
            return int(value)
        if not isinstance(value, list) or len(value) != len(self.sliders):
            raise Refused(f"label {shown(value)} refused: expected a list of {len(self.sliders)} numbers")
        for slider, x in zip(self.sliders, value):
            if not _finite(x) or not slider.low <= x <= slider.high:
                raise Refused(
                    f"label {shown(value)} refused: {slider.name} must be a number in [{slider.low:g}, {slider.high:g}]"
                )
        return [float(x) for x in np.asarray(value, dtype=np.float32)]

    def as_json(self) -> dict[str, Any]:
        """The form as the page reads it: its classes or sliders, what it asks, and its marks."""
        if self.classes:
            asks = self.asks or "Choose the class the expert would choose in the state shown."
            return {"classes": list(self.classes), "asks": asks, "marks": {str(i): word for i, word in self.marks}}
        asks = self.asks or "Set each dimension to the action the expert would take in the state shown."
        return {"sliders": [{"name": s.name, "low": s.low, "high": s.high} for s in self.sliders], "asks": asks}


def _finite(x: Any) -> bool:
    """Whether ``x`` is a JSON number (not a boolean) with a finite float value."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:  # an integer beyond float's range
        return False


def default_form(space: gym.Space) -> LabelForm:
    """A form from an action space alone: classes named by index, or a slider per dimension within the bounds."""
    if isinstance(space, gym.spaces.Discrete):
        return LabelForm(classes=tuple(str(int(space.start) + i) for i in range(int(space.n))))
    if isinstance(space, gym.spaces.Box) and np.isfinite(space.low).all() and np.isfinite(space.high).all():
        low, high = space.low.reshape(-1), space.high.reshape(-1)
        return LabelForm(
            sliders=tuple(Slider(f"dimension {i}", float(a), float(b)) for i, (a, b) in enumerate(zip(low, high)))
        )
    raise UserError(
        f"no label form for action space {space}: give the task a person_labels() method returning a LabelForm "
        "(docs/label.md)"
    )


#: CarRacing's 20 steering classes, left to right (the env turns the wheels towards -action[0]: + steers right).
#: The count is even, so no class is exactly straight: the two nearest zero (+-0.021 rad) are marked so.
STEERING = LabelForm(
    classes=tuple(f"{'left' if v < 0 else 'right'} {abs(float(v)):.2f}" for v in STEERING_VALUES),
    asks=(
        "Steering only (the scripted expert drives gas and brake): the angle the front wheels turn to, in radians, "
        f"from left {-float(STEERING_VALUES[0]):.2f} (full left) to right {float(STEERING_VALUES[-1]):.2f} (full "
        f"right), {float(STEERING_VALUES[1] - STEERING_VALUES[0]):.3f} apart. No class is exactly straight: the two "
        f"marked straight (±{float(np.abs(STEERING_VALUES).min()):.3f}) are the nearest."
    ),
    marks=tuple((int(i), "straight") for i in sorted(np.argsort(np.abs(STEERING_VALUES))[:2])),
)
#: Fetch's gripper displacement, one slider per axis.
DISPLACEMENT = LabelForm(sliders=tuple(Slider(axis, -1.0, 1.0) for axis in ("x", "y", "z")))


def label_form(task: Task) -> LabelForm:
    """How a person labels ``task``: its own ``person_labels()``, the packaged task's form, or :func:`default_form`.

    Raises:
        UserError: the task's form does not fit its action space (a class per action, a slider per dimension).
    """
    declared = getattr(task, "person_labels", None)
    form = (
        declared() if callable(declared) else _packaged(task.pistar_task()) or default_form(task.learner_action_space)
    )
    if not isinstance(form, LabelForm) or bool(form.classes) != task.is_discrete or form.size != task.label_dim():
        kind = "classes" if task.is_discrete else "sliders"
        raise UserError(
            f"task {task.name!r}'s person_labels() must return a LabelForm with {task.label_dim()} {kind}, got {form!r}"
        )
    return form


def _packaged(task: Task) -> LabelForm | None:
    if isinstance(task, CarRacingTask):
        return STEERING
    fetch = sys.modules.get("metadagger.tasks.fetch.task")  # loaded wherever a FetchTask exists
    if fetch is not None and isinstance(task, fetch.FetchTask):
        return DISPLACEMENT
    return None
