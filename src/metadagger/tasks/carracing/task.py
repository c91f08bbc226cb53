"""The CarRacing task: the learner steers (20 classes), the PID expert drives gas and brake.

``metadagger/CarRacingSteer-v0`` (entry point :func:`make_steer_env`) is the learner-facing env:
``Discrete(20)`` actions, each one of :data:`STEERING_VALUES`; gas and brake come from the expert,
whose snapped steering labels every observation (``info["expert_label"]``). Success is the paper's
rule: every track tile visited within the step limit.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv, Task
from metadagger.tasks.carracing.expert import STEER_LIMIT, PIDExpert

#: The 20 steering values (the env's ``action[0]``; +1 steers right) the learner chooses from.
#: The front wheels of gymnasium's car stop at +-0.4 rad (``car_dynamics``), and the env turns them
#: towards ``-action[0]`` radians, so every value beyond +-0.4 gives the same wheel angle. The 20
#: classes therefore cover exactly the reachable range [-0.4, 0.4] evenly (steps of 0.042 rad, 2.4
#: degrees). The count is even, so there is no exact zero: "straight" is +-0.021 rad.
STEERING_VALUES: np.ndarray = np.linspace(-STEER_LIMIT, STEER_LIMIT, 20).astype(np.float32)
STEERING_VALUES.flags.writeable = False


class CarRacingTask(Task):
    """CarRacing as a metadagger task (see the module docstring).

    Args:
        max_episode_steps: step limit of one episode (the paper's 1000).
        expert: the expert driving gas and brake and labelling states; a default
            :class:`~metadagger.tasks.carracing.expert.PIDExpert` if ``None``.
    """

    name = "carracing"
    learner_env_id = "metadagger/CarRacingSteer-v0"

    def __init__(self, *, max_episode_steps: int = 1000, expert: PIDExpert | None = None):
        if (
            isinstance(max_episode_steps, bool)
            or not isinstance(max_episode_steps, (int, np.integer))
            or max_episode_steps <= 0
        ):
            raise UserError(f"max_episode_steps must be a positive integer, got {max_episode_steps!r}; pass e.g. 1000")
        self.max_episode_steps = int(max_episode_steps)
        self._expert = expert or PIDExpert()

    @property
    def learner_action_space(self) -> gym.spaces.Discrete:
        """``Discrete(20)``: an index into :data:`STEERING_VALUES`."""
        return gym.spaces.Discrete(len(STEERING_VALUES))

    def make_base_env(self, **kwargs: Any) -> gym.Env:
        """A :class:`~metadagger.tasks.carracing.env.CarRacingFast` (upstream kwargs and ``render``)."""
        from metadagger.tasks.carracing.env import CarRacingFast

        return CarRacingFast(**kwargs)

    def expert(self, env: gym.Env) -> np.ndarray:
        """The PID expert's ``[steer, gas, brake]`` for ``env``'s current state."""
        return self._expert(env)

    def to_label(self, action: np.ndarray) -> int:
        """Index of the steering value nearest ``action[0]``."""
        return int(np.argmin(np.abs(STEERING_VALUES - float(np.asarray(action).reshape(-1)[0]))))

    def combine(self, label: Any, action: np.ndarray) -> np.ndarray:
        """``[STEERING_VALUES[label], action[1], action[2]]`` as float32."""
        index = int(label)
        if not 0 <= index < len(STEERING_VALUES) or index != label:
            raise ValueError(f"steering label must be an integer in [0, {len(STEERING_VALUES) - 1}], got {label!r}")
        action = np.asarray(action, dtype=np.float32).reshape(-1)
        return np.array([STEERING_VALUES[index], action[1], action[2]], dtype=np.float32)

    def is_success(self, env: gym.Env) -> bool:
        """Every tile visited (tiles 0 and 1 count at reset, so this is one full lap)."""
        base = env.unwrapped
        return bool(base.tile_visited_count == len(base.track))


def make_steer_env(*, max_episode_steps: int = 1000, **kwargs: Any) -> LearnerEnv:
    """Entry point of ``metadagger/CarRacingSteer-v0``: the learner-facing CarRacing env.

    Args:
        max_episode_steps: step limit of one episode.
        **kwargs: passed to :class:`~metadagger.tasks.carracing.env.CarRacingFast`
            (e.g. ``render_mode``, ``render``).
    """
    return CarRacingTask(max_episode_steps=max_episode_steps).make_env(**kwargs)
