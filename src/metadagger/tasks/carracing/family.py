"""The CarRacing family: every seed's car has its own steering gain and offset (docs/families.md).

Between the learner's steering command ``c`` and the car, seed ``s`` applies
``steer = clip(g * c + o, -1, 1)``: a mirrored (``g < 0``), over- or under-steering, misaligned car.
The PID expert compensates (it commands ``(steer* - o) / g`` for the wheel angle ``steer*`` it
wants), so its labels are the right commands for that car; the learner sees only the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv
from metadagger.tasks.carracing.expert import STEER_LIMIT
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask
from metadagger.tasks.family import FamilyTask, Variation


@dataclass(frozen=True)
class SteeringVariation(Variation):
    """``steer = clip(g * command + o, -1, 1)`` with ``g = sign * gain``.

    ``sign`` is -1 (a mirrored car) with probability ``mirror_probability``; ``gain`` is
    log-uniform on ``gain_range``; ``o`` is uniform on ``[-max_offset, max_offset]``.
    """

    mirror_probability: float = 0.5
    gain_range: tuple[float, float] = (0.8, 2.0)
    max_offset: float = 0.1

    def __post_init__(self) -> None:
        low, high = self.gain_range
        if not 0.0 <= self.mirror_probability <= 1.0:
            raise UserError(f"mirror_probability must be in [0, 1], got {self.mirror_probability}")
        if not 0.0 < low <= high:
            raise UserError(f"gain_range must be (low, high) with 0 < low <= high, got {self.gain_range}")
        if not 0.0 <= self.max_offset < STEER_LIMIT:
            raise UserError(f"max_offset must be in [0, {STEER_LIMIT}), got {self.max_offset}")

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        sign = -1.0 if rng.random() < self.mirror_probability else 1.0
        low, high = self.gain_range
        gain = float(np.exp(rng.uniform(np.log(low), np.log(high))))
        return {"gain": sign * gain, "offset": float(rng.uniform(-self.max_offset, self.max_offset))}

    def apply(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        applied = np.array(action, dtype=np.float32, copy=True)
        applied[0] = np.clip(variation["gain"] * applied[0] + variation["offset"], -1.0, 1.0)
        return applied

    def compensate(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        command = np.array(action, dtype=np.float32, copy=True)
        command[0] = np.clip((command[0] - variation["offset"]) / variation["gain"], -STEER_LIMIT, STEER_LIMIT)
        return command

    def size(self, variation: dict[str, float]) -> float:
        """Mean wheel-angle error (radians) of commanding the nominal angle, over the 20 classes."""
        wheel = np.clip(variation["gain"] * STEERING_VALUES + variation["offset"], -STEER_LIMIT, STEER_LIMIT)
        return float(np.mean(np.abs(wheel - STEERING_VALUES)))


class CarRacingFamily(FamilyTask):
    """``carracing-family``: :class:`~metadagger.tasks.carracing.task.CarRacingTask` with a
    :class:`SteeringVariation` per seed.

    Args:
        max_episode_steps: step limit of one episode.
        mirror_probability, gain_range, max_offset: the variation's distribution.
    """

    def __init__(
        self,
        *,
        max_episode_steps: int = 1000,
        mirror_probability: float = 0.5,
        gain_range: tuple[float, float] = (0.8, 2.0),
        max_offset: float = 0.1,
    ):
        variation = SteeringVariation(
            mirror_probability=mirror_probability, gain_range=tuple(gain_range), max_offset=max_offset
        )
        super().__init__(
            CarRacingTask(max_episode_steps=max_episode_steps),
            variation,
            name="carracing-family",
            learner_env_id="metadagger/CarRacingSteerFamily-v0",
        )


def make_family_env(*, max_episode_steps: int = 1000, **kwargs: Any) -> LearnerEnv:
    """Entry point of ``metadagger/CarRacingSteerFamily-v0``: the family's learner env."""
    return CarRacingFamily(max_episode_steps=max_episode_steps).make_env(**kwargs)
