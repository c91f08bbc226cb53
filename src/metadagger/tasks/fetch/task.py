"""The ``fetch`` task: FetchPickAndPlace from pixels, the learner moves, the expert grips.

Paper section 4.2: the learner outputs the gripper's x, y, z displacement from a 64x64 image; the
expert always drives the fourth action dimension (the fingers) and labels every state.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv, Task
from metadagger.tasks.fetch.env import FetchPickAndPlacePixels, fetch_is_success
from metadagger.tasks.fetch.expert import FetchExpert

#: Episode length of the paper's Fetch setting.
MAX_EPISODE_STEPS = 50


class FetchTask(Task):
    """FetchPickAndPlace with the goal at the cube's height; success = cube at the goal at the end.

    Args:
        expert: Callable returning the full action for a Fetch env's current state; defaults to
            the scripted :class:`~metadagger.tasks.fetch.expert.FetchExpert` (a
            :class:`~metadagger.tasks.fetch.expert.DistilledFetchExpert` also fits).
    """

    name = "fetch"
    learner_env_id = "metadagger/FetchPickAndPlaceXYZ-v0"
    max_episode_steps = MAX_EPISODE_STEPS
    #: A keypoint trunk (docs/fetch.md, "The policy"): three 3x3 convolutions keeping 32x32 maps,
    #: a spatial softmax, then 128 and 64 units; the head maps 64 features to x, y, z (195 weights).
    policy_arch = {
        "conv_channels": (16, 16, 32),
        "kernel_sizes": (3, 3, 3),
        "strides": (2, 1, 1),
        "hidden": (128, 64),
        "spatial_softmax": True,
    }

    def __init__(
        self, *, expert: Callable[[gym.Env], np.ndarray] | None = None, max_episode_steps: int = MAX_EPISODE_STEPS
    ):
        if max_episode_steps < 1:
            raise UserError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.max_episode_steps = int(max_episode_steps)
        self._expert = FetchExpert() if expert is None else expert

    @property
    def learner_action_space(self) -> gym.spaces.Box:
        return gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def make_base_env(self, **kwargs: Any) -> FetchPickAndPlacePixels:
        return FetchPickAndPlacePixels(**kwargs)

    def expert(self, env: gym.Env) -> np.ndarray:
        return np.asarray(self._expert(env), dtype=np.float32)

    def to_label(self, action: np.ndarray) -> np.ndarray:
        return np.asarray(action, dtype=np.float32)[:3].copy()

    def combine(self, label: Any, action: np.ndarray) -> np.ndarray:
        xyz = np.asarray(label, dtype=np.float32).reshape(-1)
        if xyz.shape != (3,):
            raise ValueError(f"a fetch label is an (x, y, z) displacement of shape (3,), got shape {xyz.shape}")
        fingers = np.asarray(action, dtype=np.float32).reshape(-1)[3]
        return np.append(np.clip(xyz, -1.0, 1.0), fingers).astype(np.float32)

    def is_success(self, env: gym.Env) -> bool:
        return fetch_is_success(env)


def make_xyz_env(**kwargs: Any) -> LearnerEnv:
    """Entry point of ``metadagger/FetchPickAndPlaceXYZ-v0``: the learner-facing env (Box(3) actions).

    Keyword arguments go to :class:`~metadagger.tasks.fetch.env.FetchPickAndPlacePixels`.
    """
    task = FetchTask()
    return LearnerEnv(task.make_base_env(**kwargs), task=task, max_episode_steps=task.max_episode_steps)


def expert_success(*, seeds: Sequence[int], expert: Callable[[gym.Env], np.ndarray] | None = None) -> list[bool]:
    """Drive the learner env with the expert's own labels, one episode per seed; success per seed.

    This is how the expert itself fares in the learner's setting (pixels env, goal at the
    cube's height, 50 steps, the expert gripping).
    """
    env = FetchTask(expert=expert).make_env()
    try:
        outcomes = []
        for seed in seeds:
            _, info = env.reset(seed=int(seed))
            done = False
            while not done:
                _, _, terminated, truncated, info = env.step(info["expert_label"])
                done = terminated or truncated
            outcomes.append(bool(info["is_success"]))
        return outcomes
    finally:
        env.close()
