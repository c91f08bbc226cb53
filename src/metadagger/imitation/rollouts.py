"""Rollouts in a learner env: the learner (or the expert) acts, the expert labels every state."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from metadagger.imitation.data import Dataset, unkept_images
from metadagger.policies import Policy


class EarlyStop(Protocol):
    """Ends a rollout early, counted as a failure (e.g. the learner strays too far from the expert)."""

    def reset(self) -> None:
        """Forget the previous episode."""

    def update(self, learner_action: Any, expert_label: Any) -> bool:
        """Record one step; True means stop now and count the episode as a failure."""


@dataclass(frozen=True)
class Trajectory:
    """One episode in a learner env.

    Attributes:
        obs: (T, H, W, C) uint8 observations the learner acted on; for an episode whose images
            were not kept (:func:`~metadagger.imitation.data.images_kept`), a stand-in of that
            shape that holds no memory.
        expert_labels: the expert's label for each observation: (T,) int64 or (T, d) float32.
        learner_actions: the action taken at each observation, same layout as ``expert_labels``.
        reward: summed env reward.
        steps: env steps taken (= T).
        success: the task's success rule at the end; False if an early stop fired.
        expert_queries: expert labels kept for training (= T).
        seed: the ``reset`` seed.
        step_rewards: (T,) float32 env reward of each step (``reward`` is their sum).
        final_obs: the observation after the last step (never acted on).
        final_label: the expert's label of ``final_obs`` (computed by the env, never trained on).
        terminated: whether the env terminated (False: truncated, capped or early-stopped).
        early_stopped: whether an :class:`EarlyStop` ended the episode.
        variation: the task family's variation of this episode (``info["variation"]`` at reset);
            None for a plain task.
        features: (T, feature_dim) float32 trunk features the learner acted on, where lockstep
            lanes computed them (:mod:`metadagger.imitation.lanes`); None for an episode rolled
            out alone.
    """

    obs: np.ndarray
    expert_labels: np.ndarray
    learner_actions: np.ndarray
    reward: float
    steps: int
    success: bool
    expert_queries: int
    seed: int
    step_rewards: np.ndarray
    final_obs: np.ndarray
    final_label: Any
    terminated: bool
    early_stopped: bool = False
    variation: dict[str, float] | None = None
    features: np.ndarray | None = None

    def to_dataset(self) -> Dataset:
        """The (observation, expert label) pairs of this episode, with the features it acted on where it has them."""
        return Dataset(obs=self.obs, labels=self.expert_labels, features=self.features)


def stack_labels(values: list[Any] | np.ndarray, discrete: bool) -> np.ndarray:
    """Labels or actions in the layout of :class:`Trajectory`: (N,) int64 or (N, d) float32."""
    if discrete:
        return np.asarray(values, dtype=np.int64).reshape(len(values))
    return np.asarray(values, dtype=np.float32).reshape(len(values), -1)


@dataclass(frozen=True)
class ActionNoise:
    """DART's perturbation of the action the expert executes (Laskey et al. 2017, "DART: Noise
    Injection for Robust Imitation Learning"); each visited state is still labelled with the
    expert's own, unperturbed action. With classes, the executed class is another one, drawn
    uniformly, with probability ``scale``; with action vectors, Gaussian noise of standard
    deviation ``scale`` is added to each coordinate (clipped to the action space)."""

    scale: float
    """The perturbation's probability (classes, in [0, 1]) or standard deviation (vectors, >= 0)."""
    stream: tuple[int, ...]
    """Seeds the episode's own perturbations (e.g. its env seed and its index among the seed's episodes)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale >= 0):
            raise ValueError(f"a DART noise scale must be finite and >= 0, got {self.scale!r}")


class EpisodeRecorder:
    """One episode in the making: the env reset with its seed, then one :meth:`step` per action.

    :func:`rollout` and the lockstep lanes (:mod:`metadagger.imitation.lanes`) both record through
    it, so an episode means the same in either: every acted-on observation is kept with the
    expert's label of it, the action taken and the reward that followed.

    Args:
        env: a learner env (``info["expert_label"]`` labels each returned observation).
        seed: reset seed.
        max_steps: stop after this many steps even if the env has not ended (not a success).
        early_stop: stops the episode as a failure when its ``update`` returns True.
        keep_images: keep every acted-on image in the trajectory; False gives a stand-in
            (:func:`~metadagger.imitation.data.unkept_images`) for an episode whose features are all that is read later.
        noise: where the expert drives, how its executed action is perturbed (:class:`ActionNoise`,
            DART); None: it executes its own label.
    """

    def __init__(
        self,
        env: gym.Env,
        *,
        seed: int,
        max_steps: int | None = None,
        early_stop: EarlyStop | None = None,
        keep_images: bool = True,
        noise: ActionNoise | None = None,
    ) -> None:
        if max_steps is not None and max_steps <= 0:
            raise ValueError(f"max_steps must be positive or None, got {max_steps}")
        self.env, self.seed, self.max_steps, self.early_stop = env, int(seed), max_steps, early_stop
        self.keep_images = keep_images
        self.discrete = isinstance(env.action_space, gym.spaces.Discrete)
        if noise is not None and self.discrete and noise.scale > 1:
            raise ValueError(f"a DART noise scale on classes is a probability in [0, 1], got {noise.scale!r}")
        self.noise = noise
        self._noise_rng = None if noise is None else np.random.default_rng(list(noise.stream))
        self.obs, self.info = env.reset(seed=seed)
        self.variation = self.info.get("variation")
        if early_stop is not None:
            early_stop.reset()
        self.observations: list[np.ndarray] = []
        self.steps = 0
        self.labels: list[Any] = []
        self.actions: list[Any] = []
        self.rewards: list[float] = []
        self.success, self.stopped, self.terminated = False, False, False

    @property
    def label(self) -> Any:
        """The expert's label of the observation the next action acts on."""
        return self.info["expert_label"]

    def expert_action(self) -> Any:
        """What the expert executes on the current observation: its label, perturbed where the
        episode has :class:`ActionNoise`."""
        label = self.info["expert_label"]
        if self.noise is None or self._noise_rng is None:
            return label
        space, rng = self.env.action_space, self._noise_rng
        if self.discrete:
            if space.n < 2 or rng.random() >= self.noise.scale:
                return label
            other = int(rng.integers(space.n - 1))  # uniform over the other classes
            return other + int(other >= int(label))
        label = np.asarray(label, dtype=np.float32)
        noisy = label + rng.normal(0.0, self.noise.scale, size=label.shape).astype(np.float32)
        return np.clip(noisy, space.low, space.high).astype(np.float32)

    def step(self, action: Any) -> bool:
        """Take ``action`` on the current observation; True when the episode has ended."""
        label = self.info["expert_label"]
        if self.keep_images:  # copied because an env may reuse its observation buffer between steps
            self.observations.append(np.array(self.obs, dtype=np.uint8, copy=True))
        self.steps += 1
        self.labels.append(label)
        self.actions.append(action)
        self.obs, step_reward, terminated, truncated, self.info = self.env.step(action)
        self.terminated = bool(terminated)
        self.rewards.append(float(step_reward))
        # the action was executed, so the step counts even when the early stop then fires
        self.stopped = self.early_stop is not None and self.early_stop.update(action, label)
        if self.stopped:
            return True
        if terminated or truncated:
            self.success = bool(self.info.get("is_success", False))
            return True
        return self.max_steps is not None and self.steps >= self.max_steps

    def trajectory(self) -> Trajectory:
        """The finished episode."""
        steps = self.steps
        images = np.asarray(self.obs).shape
        return Trajectory(
            obs=np.stack(self.observations) if self.keep_images else unkept_images(steps, images),
            expert_labels=stack_labels(self.labels, self.discrete),
            learner_actions=stack_labels(self.actions, self.discrete),
            reward=float(sum(self.rewards)),
            steps=steps,
            success=self.success,
            expert_queries=steps,
            seed=self.seed,
            step_rewards=np.asarray(self.rewards, dtype=np.float32),
            final_obs=np.array(self.obs, dtype=np.uint8, copy=True),
            final_label=self.info["expert_label"],
            terminated=self.terminated and not self.stopped,
            early_stopped=self.stopped,
            variation=self.variation,
        )


def rollout(
    env: gym.Env,
    *,
    seed: int,
    policy: Policy | None,
    max_steps: int | None = None,
    early_stop: EarlyStop | None = None,
    noise: ActionNoise | None = None,
) -> Trajectory:
    """Run one episode from ``env.reset(seed=seed)``.

    Args:
        env: a learner env (``info["expert_label"]`` labels each returned observation).
        seed: reset seed.
        policy: the learner; ``None`` lets the expert act with its own labels (a demonstration).
        max_steps: stop after this many steps even if the env has not ended (not a success).
        early_stop: stops the episode as a failure when its ``update`` returns True.
        noise: where the expert acts, how its executed action is perturbed (DART); its labels stay its own.

    Returns:
        The trajectory; every visited observation is labelled by the expert.
    """
    if noise is not None and policy is not None:
        raise ValueError("noise perturbs the expert's executed action: pass policy=None with it")
    episode = EpisodeRecorder(env, seed=seed, max_steps=max_steps, early_stop=early_stop, noise=noise)
    while not episode.step(episode.expert_action() if policy is None else policy(episode.obs)):
        pass
    return episode.trajectory()
