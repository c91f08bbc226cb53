"""The task interface: what makes a Gymnasium environment pluggable into metadagger.

A task bundles a base environment (upstream action space), an expert that reads the simulator
state, the split of a full action into the learner's part and the part the expert always drives,
and the paper's success rule. :class:`LearnerEnv` turns any task into the learner-facing env.
"""

from __future__ import annotations

import abc
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from metadagger.tasks.gym_ids import register_envs


class Task(abc.ABC):
    """One environment with its expert: an env per seed (the seed draws the layout), the expert,
    the split of a full action into the learner's part and the expert's, and a success rule.

    A task *family* is a Task whose seeds also draw a variation of the system
    (:class:`~metadagger.tasks.family.FamilyTask`, docs/families.md). Subclass Task for your own
    environment and register it with :func:`metadagger.tasks.register_task`.
    """

    #: Short name used on the command line (``--task NAME``).
    name: str
    #: Gymnasium id of the learner-facing env (registered by :func:`~metadagger.tasks.gym_ids.register_envs`).
    learner_env_id: str
    #: Step limit of one episode.
    max_episode_steps: int
    #: Policy architecture overrides for this task (``conv_channels``, ``kernel_sizes``, ``hidden``,
    #: ``strides``, ``spatial_softmax``).
    policy_arch: dict = {}

    @property
    @abc.abstractmethod
    def learner_action_space(self) -> gym.Space:
        """The learner's action space: ``Discrete`` (classification head) or ``Box`` (regression)."""

    @abc.abstractmethod
    def make_base_env(self, **kwargs: Any) -> gym.Env:
        """A new base env with the upstream action space (no time limit)."""

    @abc.abstractmethod
    def expert(self, env: gym.Env) -> np.ndarray:
        """The expert's full action for the current state of a base env (ours or upstream's)."""

    @abc.abstractmethod
    def to_label(self, action: np.ndarray) -> Any:
        """The learner's part of a full action (a class index or a vector)."""

    @abc.abstractmethod
    def combine(self, label: Any, action: np.ndarray) -> np.ndarray:
        """A full action: the learner's part ``label`` plus the expert's remaining part of ``action``."""

    @abc.abstractmethod
    def is_success(self, env: gym.Env) -> bool:
        """The paper's success rule, read at the end of an episode."""

    def make_env(self, seed: int | None = None, **kwargs: Any) -> gym.Env:
        """The learner-facing env; if ``seed`` is given it is reset once with that seed. Registers
        metadagger's Gymnasium ids (:func:`~metadagger.tasks.gym_ids.register_envs`) first."""
        register_envs()
        env = LearnerEnv(self.make_base_env(**kwargs), task=self, max_episode_steps=self.max_episode_steps)
        if seed is not None:
            env.reset(seed=seed)
        return env

    @property
    def options(self) -> dict[str, Any]:
        """The keyword arguments that make this task a variant of its kind, beyond its episode length
        (a stage's stamp records them: artifacts of one variant are never read as another's); none
        by default."""
        return {}

    def pistar_task(self) -> "Task":
        """The task pi* is trained on: this one (a family returns its nominal member)."""
        return self

    def variation_of(self, seed: int) -> dict[str, float] | None:
        """The variation ``seed`` draws in a task family; ``None`` for a plain task."""
        return None

    def variation_size(self, variation: dict[str, float]) -> float:
        """How far ``variation`` is from the family's nominal member (0 for a plain task)."""
        return 0.0

    @property
    def is_discrete(self) -> bool:
        """Whether the learner's action is a class index (cross-entropy) or a vector (MSE)."""
        return isinstance(self.learner_action_space, gym.spaces.Discrete)

    def label_dim(self) -> int:
        """Number of network outputs: classes for Discrete, vector length for Box."""
        space = self.learner_action_space
        if isinstance(space, gym.spaces.Discrete):
            return int(space.n)
        return int(np.prod(space.shape))


class LearnerEnv(gym.Wrapper):
    """The learner-facing env of a task: the learner acts in its own action space, the expert
    drives the rest of the action and labels every state.

    ``info["expert_label"]`` is the expert's label for the observation just returned (at reset
    and after each step), ``info["expert_action"]`` its full action. At the end of an episode
    (terminated or truncated) ``info["is_success"]`` holds the task's success rule.
    """

    def __init__(self, env: gym.Env, *, task: Task, max_episode_steps: int):
        super().__init__(env)
        if max_episode_steps <= 0:
            raise ValueError(f"max_episode_steps must be positive, got {max_episode_steps}")
        self.task = task
        self.action_space = task.learner_action_space
        self.max_episode_steps = int(max_episode_steps)
        self._elapsed = 0
        self._expert_action: np.ndarray | None = None

    def _label_info(self, info: dict[str, Any]) -> dict[str, Any]:
        self._expert_action = np.asarray(self.task.expert(self.env), dtype=np.float32)
        info = dict(info)
        info["expert_action"] = self._expert_action
        info["expert_label"] = self.task.to_label(self._expert_action)
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._elapsed = 0
        return obs, self._label_info(info)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._expert_action is None:
            raise RuntimeError("call reset() before step()")
        full = self.task.combine(action, self._expert_action)
        obs, reward, terminated, truncated, info = self.env.step(full)
        self._elapsed += 1
        truncated = bool(truncated or self._elapsed >= self.max_episode_steps)
        info = self._label_info(info)
        if terminated or truncated:
            info["is_success"] = bool(self.task.is_success(self.env))
        return obs, reward, bool(terminated), truncated, info
