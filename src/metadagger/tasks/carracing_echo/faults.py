"""Steering faults the expert sees and the learner's frame does not: CarRacing's hidden context.

A fault is a burst of ``steps`` steps during which the car adds ``offset`` (its sign drawn per
burst) to every executed steering command; a burst starts on a step without one with probability
``rate``, drawn from the episode's reset seed, so an episode's faults are the same whoever drives.
The expert reads the simulator, the fault included, and steers against it (its label is the
steering that, with the fault added, executes what it wants), so its own episodes stay on its
line. The learner's frame does not show the fault, so where the learner drives a burst pushes the
car off that line, into states the expert's demonstration never visits: the recovery only labels
on the learner's own states show (Swamy et al. 2022, "Sequence Model Imitation Learning with
Unobserved Contexts"; Spencer et al. 2021).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError

#: The generator stream of the fault schedule, beside the reset seed.
FAULT_STREAM = 0x5EED_FA17


def check_faults(rate: Any, steps: Any, offset: Any) -> None:
    """Raise a :class:`UserError` unless the fault settings are a probability, a positive step count
    and a steering offset in [0, 2]."""
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 <= rate <= 1:
        raise UserError(f"fault_rate must be a probability in [0, 1], got {rate!r}; e.g. 0.01 (0: no faults)")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise UserError(f"fault_steps must be a positive integer, got {steps!r}; e.g. 20")
    if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not 0 <= offset <= 2:
        raise UserError(f"fault_offset must be a steering offset in [0, 2], got {offset!r}; e.g. 0.3")


class SteeringFaults(gym.Wrapper):
    """Adds :attr:`next_offset` to the steering (``action[0]``) of the next step, clipped to [-1, 1],
    and draws the offset of the step after (see the module docstring).

    Args:
        env: a CarRacing env whose action's first entry is the steering.
        rate: the probability that a burst starts on a step without one.
        steps: a burst's length in steps.
        offset: the steering a burst adds, with a sign drawn per burst.
    """

    def __init__(self, env: gym.Env, *, rate: float, steps: int, offset: float) -> None:
        super().__init__(env)
        check_faults(rate, steps, offset)
        self.rate, self.steps, self.offset = float(rate), int(steps), float(offset)
        self._rng = np.random.default_rng(FAULT_STREAM)
        self._left, self._sign = 0, 0.0
        self.next_offset = 0.0
        """The steering the next step adds to the command (0 outside a burst)."""

    def _draw(self) -> None:
        if self._left == 0 and self.rate > 0 and self._rng.random() < self.rate:
            self._left, self._sign = self.steps, (1.0 if self._rng.random() < 0.5 else -1.0)
        self.next_offset = self._sign * self.offset if self._left > 0 else 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        seed = kwargs.get("seed")
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), FAULT_STREAM])
        self._left, self._sign = 0, 0.0
        obs, info = self.env.reset(**kwargs)
        self._draw()
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        executed = np.array(action, dtype=np.float32, copy=True).reshape(-1)
        executed[0] = np.clip(executed[0] + self.next_offset, -1.0, 1.0)
        if self._left > 0:
            self._left -= 1
        result = self.env.step(executed)
        self._draw()
        return result
