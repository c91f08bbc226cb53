"""Task families: seeds that differ in more than the layout (docs/families.md).

A :class:`Variation` draws, from the seed alone, a few numbers that change what the right learner
command is (a steering gain, a rotation of the commanded displacement). :class:`FamilyTask` wraps
any task with one: inside the env, between the full action and the simulator, the variation is
applied (:class:`VariedEnv`); the expert compensates for it, so its labels are the commands that
do what it wants on *this* seed's system. The variation is reported in ``info["variation"]`` and
never reaches the observation: a learner must infer it from the seed's demonstration.

pi* is trained on the family's nominal member (the base task, no variation): one shared head
cannot fit seeds whose right commands contradict each other, and the trunk only has to see the
scene. Every seed after that (pairs, evaluation) draws its variation.
"""

from __future__ import annotations

import abc
from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.tasks.base import Task


class Variation(abc.ABC):
    """How the members of a family differ: a distribution over dicts of floats, its effect on a
    full action, and the expert's compensation for it."""

    #: Mixed into the seed so the variation's random stream is not the env's own (Gymnasium
    #: seeds ``np_random`` from the same integer).
    salt: int = 0x5EED

    @abc.abstractmethod
    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        """One member's variation, drawn from ``rng``."""

    @abc.abstractmethod
    def apply(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        """The full action the simulator receives when ``action`` is commanded."""

    @abc.abstractmethod
    def compensate(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        """The command whose applied action is (as close as the action space allows to) ``action``."""

    @abc.abstractmethod
    def size(self, variation: dict[str, float]) -> float:
        """How far this member is from the nominal one (0: no variation), for tables and plots."""

    def draw(self, seed: int) -> dict[str, float]:
        """The variation of ``seed`` (a pure function of the seed)."""
        rng = np.random.default_rng([int(seed), self.salt])
        return {key: float(value) for key, value in self.sample(rng).items()}


class VariedEnv(gym.Wrapper):
    """A base env whose actions pass through its seed's variation.

    ``reset(seed=s)`` draws the variation of ``s``; a reset without a seed keeps the current one
    (or, on the very first reset, draws one from the env's own random stream).
    ``info["variation"]`` holds it after every reset and step.
    """

    def __init__(self, env: gym.Env, variation: Variation):
        super().__init__(env)
        self.family_variation = variation
        self.variation: dict[str, float] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if seed is not None:
            self.variation = self.family_variation.draw(seed)
        elif self.variation is None:
            self.variation = self.family_variation.draw(int(self.env.unwrapped.np_random.integers(2**31)))
        return obs, {**info, "variation": dict(self.variation)}

    def step(self, action: Any):
        if self.variation is None:
            raise RuntimeError("call reset() before step()")
        applied = self.family_variation.apply(self.variation, np.asarray(action, dtype=np.float32))
        obs, reward, terminated, truncated, info = self.env.step(applied)
        return obs, reward, terminated, truncated, {**info, "variation": dict(self.variation)}


class FamilyTask(Task):
    """A task family: ``base``'s envs, expert and success rule, each seed varied by ``variation``.

    Args:
        base: the nominal task (pi* is trained on it).
        variation: what differs between seeds.
        name: the family's task name (``--task NAME``).
        learner_env_id: Gymnasium id of the family's learner env, if registered.
    """

    def __init__(self, base: Task, variation: Variation, *, name: str, learner_env_id: str = ""):
        self.base = base
        self.variation = variation
        self.name = name
        self.learner_env_id = learner_env_id
        self.max_episode_steps = base.max_episode_steps
        self.policy_arch = base.policy_arch

    @property
    def learner_action_space(self) -> gym.Space:
        """The base task's learner action space."""
        return self.base.learner_action_space

    def make_base_env(self, **kwargs: Any) -> VariedEnv:
        """The base task's env behind a :class:`VariedEnv`."""
        return VariedEnv(self.base.make_base_env(**kwargs), self.variation)

    def expert(self, env: gym.Env) -> np.ndarray:
        """The base expert's action, compensated for ``env``'s variation."""
        wanted = np.asarray(self.base.expert(env), dtype=np.float32)
        varied = _varied_env(env)
        return np.asarray(self.variation.compensate(varied.variation, wanted), dtype=np.float32)

    def to_label(self, action: np.ndarray) -> Any:
        """As the base task."""
        return self.base.to_label(action)

    def combine(self, label: Any, action: np.ndarray) -> np.ndarray:
        """As the base task (the variation is applied after, inside the env)."""
        return self.base.combine(label, action)

    def is_success(self, env: gym.Env) -> bool:
        """The base task's success rule."""
        return self.base.is_success(env)

    def pistar_task(self) -> Task:
        """The nominal member: the base task."""
        return self.base

    def variation_of(self, seed: int) -> dict[str, float] | None:
        """The variation ``seed`` draws."""
        return self.variation.draw(seed)

    def variation_size(self, variation: dict[str, float]) -> float:
        """How far ``variation`` is from the nominal member."""
        return float(self.variation.size(variation))


def _varied_env(env: gym.Env) -> VariedEnv:
    """The :class:`VariedEnv` in ``env``'s wrapper chain."""
    while not isinstance(env, VariedEnv):
        if not isinstance(env, gym.Wrapper):
            raise TypeError(f"{env!r} has no VariedEnv: a family's expert needs the family's own env")
        env = env.env
    return env
