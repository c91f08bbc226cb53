"""CarRacing whose frame echoes the steering just executed: a task where the expert's labels matter.

``carracing-echo`` (``metadagger/CarRacingEcho-v0``) is :class:`~metadagger.tasks.carracing.task.CarRacingTask`
with a band across the top of every frame that marks the steering class executed on the step
before it. In the expert's demonstration the mark is the expert's own last command, which predicts
its next one almost always (its steering is smooth), so BC can fit the demonstration by reading the
mark; when the learner drives, the mark is the learner's own last command, and a head that copies
it keeps steering as it did (causal confusion: de Haan et al. 2019, "Causal Confusion in
Imitation Learning"; "brake predicts brake" in Spencer et al. 2021). Labels on the learner's own
states, where its mark and the expert's command part, are what break the echo; more training on
the demonstration does not (docs/carracing-echo.md).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv
from metadagger.tasks.carracing.expert import STEER_LIMIT
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask
from metadagger.tasks.carracing_echo.faults import SteeringFaults, check_faults

#: Columns of the frame the mark of one steering class covers.
MARK_WIDTH = 4


def check_echo_rows(rows: Any) -> None:
    """Raise a :class:`UserError` unless ``rows`` is a band height: an integer from 0 (no band) to 32."""
    if isinstance(rows, bool) or not isinstance(rows, int) or not 0 <= rows <= 32:
        raise UserError(f"echo_rows must be an integer from 0 (no band) to 32, got {rows!r}; e.g. 6")


class SteeringEcho(gym.Wrapper):
    """The top ``rows`` rows of each 96x96 frame cleared to black, with a white mark at the column of
    the steering class the last step executed (none after a reset): class ``c`` of the 20 covers
    columns ``[round(c * (96 - MARK_WIDTH) / 19), ... + MARK_WIDTH)``, full left at the left edge.

    Args:
        env: a CarRacing env whose action's first entry is the steering.
        rows: the band's height in pixels, 0 (the frame unchanged) to 32.
    """

    def __init__(self, env: gym.Env, *, rows: int) -> None:
        super().__init__(env)
        check_echo_rows(rows)
        self.rows = rows

    def _echo(self, obs: np.ndarray, steer: float | None) -> np.ndarray:
        if self.rows == 0:
            return obs
        obs = np.array(obs, dtype=np.uint8, copy=True)
        obs[: self.rows] = 0
        if steer is not None:
            index = int(np.argmin(np.abs(STEERING_VALUES - steer)))
            left = int(round(index * (obs.shape[1] - MARK_WIDTH) / (len(STEERING_VALUES) - 1)))
            obs[: self.rows, left : left + MARK_WIDTH] = 255
        return obs

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return self._echo(obs, None), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._echo(obs, float(np.asarray(action).reshape(-1)[0])), reward, terminated, truncated, info


class CarRacingEchoTask(CarRacingTask):
    """``carracing-echo``: CarRacing (the learner steers, the PID expert drives gas and brake) whose
    frame marks the steering executed on the step before (:class:`SteeringEcho`), with steering
    faults the expert steers against and the learner's frame does not show
    (:class:`~metadagger.tasks.carracing_echo.faults.SteeringFaults`).

    Args:
        max_episode_steps: step limit of one episode.
        echo_rows: the height of the band that marks the last steering (pixels; 0: no band).
        fault_rate: the probability that a fault starts on a step without one (0: no faults).
        fault_steps: a fault's length in steps.
        fault_offset: the steering a fault adds to every command (its sign drawn per fault).
    """

    name = "carracing-echo"
    learner_env_id = "metadagger/CarRacingEcho-v0"

    def __init__(
        self,
        *,
        max_episode_steps: int = 1000,
        echo_rows: int = 6,
        fault_rate: float = 0.0,
        fault_steps: int = 20,
        fault_offset: float = 0.3,
    ) -> None:
        super().__init__(max_episode_steps=max_episode_steps)
        check_echo_rows(echo_rows)  # now, not when the first env is made
        check_faults(fault_rate, fault_steps, fault_offset)
        self.echo_rows = echo_rows
        self.fault_rate, self.fault_steps, self.fault_offset = fault_rate, fault_steps, fault_offset

    @property
    def options(self) -> dict[str, Any]:
        """The band's height and, where there are faults, their settings: a variant of the task."""
        faults = {"fault_rate": self.fault_rate, "fault_steps": self.fault_steps, "fault_offset": self.fault_offset}
        return {"echo_rows": self.echo_rows, **(faults if self.fault_rate > 0 else {})}

    def make_base_env(self, **kwargs: Any) -> gym.Env:
        """The CarRacing env in this variant's wrappers (:meth:`wrap`)."""
        return self.wrap(super().make_base_env(**kwargs))

    def wrap(self, env: gym.Env) -> gym.Env:
        """``env`` (a CarRacing env) with the faults (:class:`SteeringFaults`, where ``fault_rate`` > 0)
        and the echo band (:class:`SteeringEcho`) of the command."""
        if self.fault_rate > 0:
            env = SteeringFaults(env, rate=self.fault_rate, steps=self.fault_steps, offset=self.fault_offset)
        return SteeringEcho(env, rows=self.echo_rows)

    def expert(self, env: gym.Env) -> np.ndarray:
        """The PID expert's ``[steer, gas, brake]``, its steering set against the coming step's fault."""
        action = np.array(super().expert(env), dtype=np.float32, copy=True)
        if self.fault_rate > 0:
            offset = float(env.get_wrapper_attr("next_offset"))
            action[0] = np.clip(action[0] - offset, -STEER_LIMIT, STEER_LIMIT)
        return action


def make_echo_env(*, max_episode_steps: int = 1000, **options: Any) -> LearnerEnv:
    """Entry point of ``metadagger/CarRacingEcho-v0``: the learner-facing env; ``options`` are
    :class:`CarRacingEchoTask`'s variant settings, the rest
    :class:`~metadagger.tasks.carracing.env.CarRacingFast`'s."""
    names = ("echo_rows", "fault_rate", "fault_steps", "fault_offset")
    variant = {name: options.pop(name) for name in names if name in options}
    return CarRacingEchoTask(max_episode_steps=max_episode_steps, **variant).make_env(**options)
