"""The Fetch family: every seed's arm moves in its own rotated, scaled frame (docs/fetch.md, "The
Fetch family"; docs/families.md).

Between the learner's command ``[dx, dy, dz, fingers]`` and the arm, seed ``s`` rotates the
horizontal displacement ``(dx, dy)`` by an angle ``theta`` about the vertical axis and multiplies
it by ``scale``, then clips it to ``[-1, 1]``; ``dz`` and the fingers are untouched. The scripted
expert compensates (it commands the inverse rotation of the displacement it wants, divided by
``scale``), so its labels are the right commands for that seed's arm; the learner sees only the
image, which is the nominal task's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv
from metadagger.tasks.family import FamilyTask, Variation
from metadagger.tasks.fetch.task import MAX_EPISODE_STEPS, FetchTask

#: Default largest rotation (radians): the whole circle.
MAX_ROTATION = math.pi
#: Default range of the displacement's scale: at least 1, so every horizontal displacement of
#: length at most 1 the expert wants stays within reach of a compensated command in [-1, 1]
#: (docs/fetch.md, "The Fetch family", for what clipping costs on longer, diagonal moves).
SCALE_RANGE = (1.0, 1.5)


def _rotate(xy: np.ndarray, angle: float) -> np.ndarray:
    """``xy`` rotated by ``angle`` radians (counter-clockwise seen from above)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * xy[0] - s * xy[1], s * xy[0] + c * xy[1]], dtype=np.float64)


@dataclass(frozen=True)
class DisplacementVariation(Variation):
    """``(dx, dy) -> clip(scale * R(theta) (dx, dy), -1, 1)``; ``dz`` and the fingers pass through.

    ``theta`` is uniform on ``[-max_rotation, max_rotation]`` (radians), ``scale`` log-uniform on
    ``scale_range``.
    """

    max_rotation: float = MAX_ROTATION
    scale_range: tuple[float, float] = SCALE_RANGE

    def __post_init__(self) -> None:
        try:
            rotation = float(self.max_rotation) if not isinstance(self.max_rotation, str) else math.nan
        except (TypeError, ValueError):
            rotation = math.nan
        if not 0.0 <= rotation <= math.pi:
            raise UserError(f"max_rotation must be a number of radians in [0, pi], got {self.max_rotation!r}")
        try:
            low, high = (math.nan if isinstance(v, str) else float(v) for v in self.scale_range)
        except (TypeError, ValueError):
            raise UserError(f"scale_range must be (low, high) with 0 < low <= high, got {self.scale_range!r}") from None
        if not (math.isfinite(low) and math.isfinite(high) and 0.0 < low <= high):
            raise UserError(f"scale_range must be (low, high) with 0 < low <= high, got {self.scale_range!r}")
        object.__setattr__(self, "max_rotation", rotation)
        object.__setattr__(self, "scale_range", (low, high))

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        theta = float(rng.uniform(-self.max_rotation, self.max_rotation))
        low, high = self.scale_range
        scale = float(np.exp(rng.uniform(np.log(low), np.log(high))))
        return {"theta": theta, "scale": scale}

    def apply(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        applied = np.array(action, dtype=np.float32, copy=True)
        xy = variation["scale"] * _rotate(applied[:2], variation["theta"])
        applied[:2] = np.clip(xy, -1.0, 1.0)
        return applied

    def compensate(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        command = np.array(action, dtype=np.float32, copy=True)
        xy = _rotate(command[:2], -variation["theta"]) / variation["scale"]
        command[:2] = np.clip(xy, -1.0, 1.0)
        return command

    def size(self, variation: dict[str, float]) -> float:
        """``|scale * e^(i theta) - 1|``: how far a unit command lands from where the nominal arm puts it."""
        return float(
            abs(variation["scale"] * complex(math.cos(variation["theta"]), math.sin(variation["theta"])) - 1.0)
        )


class FetchFamily(FamilyTask):
    """``fetch-family``: :class:`~metadagger.tasks.fetch.task.FetchTask` with a
    :class:`DisplacementVariation` per seed.

    Args:
        expert: the base task's expert (default: the scripted
            :class:`~metadagger.tasks.fetch.expert.FetchExpert`); the family compensates it.
        max_episode_steps: step limit of one episode.
        max_rotation, scale_range: the variation's distribution.
    """

    def __init__(
        self,
        *,
        expert: Callable[[gym.Env], np.ndarray] | None = None,
        max_episode_steps: int = MAX_EPISODE_STEPS,
        max_rotation: float = MAX_ROTATION,
        scale_range: tuple[float, float] = SCALE_RANGE,
    ):
        variation = DisplacementVariation(max_rotation=max_rotation, scale_range=scale_range)
        super().__init__(
            FetchTask(expert=expert, max_episode_steps=max_episode_steps),
            variation,
            name="fetch-family",
            learner_env_id="metadagger/FetchPickAndPlaceXYZFamily-v0",
        )


def make_family_env(*, max_episode_steps: int = MAX_EPISODE_STEPS, **kwargs: Any) -> LearnerEnv:
    """Entry point of ``metadagger/FetchPickAndPlaceXYZFamily-v0``: the family's learner env.

    Keyword arguments go to :class:`~metadagger.tasks.fetch.env.FetchPickAndPlacePixels`.
    """
    return FetchFamily(max_episode_steps=max_episode_steps).make_env(**kwargs)
