"""A tiny, fast image task for tests: keep a point on a winding road (16x16 egocentric view).

The road is drawn from the point's own position looking ahead, so an expert demonstration (which
never leaves the road centre) only ever shows the road starting at the centre column. A cloned
policy that makes one mistake sees views it was never trained on and drifts off the road; DAgger
labels exactly those views. The Discrete variant steers left/straight/right (cross-entropy), the
Box variant outputs the lateral move (MSE).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from metadagger.tasks.base import Task
from metadagger.tasks.family import FamilyTask, Variation

SIZE = 16


class CorridorEnv(gym.Env):
    """Steer a point up a winding road.

    ## Action Space
    ``Box(-1, 1, (1,))``: the lateral move this step.

    ## Observation Space
    ``Box(0, 255, (16, 16, 3), uint8)``: row ``15 - k`` shows the road centre ``k`` steps ahead,
    relative to the point (column 8); channel 0 is the road, channel 1 the point.

    ## Rewards
    1 per step on the road.

    ## Episode Termination
    Terminated when the point is more than ``max_offset`` from the road centre (a crash).

    ## Arguments
    ``horizon``: steps needed to finish; ``max_offset``: how far off the centre is still on the road.
    """

    metadata = {"render_modes": []}

    def __init__(self, *, horizon: int = 30, max_offset: float = 1.0):
        self.horizon = horizon
        self.max_offset = max_offset
        self.observation_space = gym.spaces.Box(0, 255, (SIZE, SIZE, 3), np.uint8)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._road = np.zeros(horizon + SIZE + 1)
        self._x = 0.0
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        # persistent curves: the road keeps its bend for a few steps, then picks a new one
        shifts = np.zeros(len(self._road))
        for i in range(1, len(shifts)):
            change = self.np_random.random() < 0.5
            shifts[i] = self.np_random.integers(-1, 2) if change else shifts[i - 1]
        shifts[:3] = 0
        self._road = np.cumsum(shifts)
        self._x, self._t = 0.0, 0
        return self._render(), {}

    @property
    def offset(self) -> float:
        """Distance of the point from the road centre (signed)."""
        return self._x - self._road[self._t]

    def expert_move(self) -> float:
        """The move that heads for the next road centre, as far as one step allows."""
        return float(np.clip(self._road[self._t + 1] - self._x, -1.0, 1.0))

    def crashed(self) -> bool:
        """Whether the point has left the road."""
        return abs(self.offset) > self.max_offset

    def step(self, action: np.ndarray):
        self._x += float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1.0, 1.0))
        self._t += 1
        crashed = self.crashed()
        return self._render(), 0.0 if crashed else 1.0, crashed, False, {}

    def _render(self) -> np.ndarray:
        image = np.zeros((SIZE, SIZE, 3), np.uint8)
        ahead = self._road[self._t : self._t + SIZE] - self._x
        columns = np.rint(SIZE // 2 + ahead).astype(int)
        rows = SIZE - 1 - np.arange(SIZE)
        visible = (columns >= 0) & (columns < SIZE)
        image[rows[visible], columns[visible], 0] = 255
        image[SIZE - 1, SIZE // 2, 1] = 255
        return image


class CorridorTask(Task):
    """The corridor as a task: success = still on the road after ``horizon`` steps."""

    max_episode_steps = 30
    policy_arch = {"conv_channels": (8, 16), "kernel_sizes": (3, 3), "hidden": (32,)}

    def __init__(self, *, discrete: bool = True):
        self.discrete = discrete
        self.name = "corridor" if discrete else "corridor-box"
        self.learner_env_id = "test/Corridor-v0"

    @property
    def learner_action_space(self) -> gym.Space:
        if self.discrete:
            return gym.spaces.Discrete(3)
        return gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def make_base_env(self, **kwargs: Any) -> gym.Env:
        return CorridorEnv(horizon=self.max_episode_steps, **kwargs)

    def expert(self, env: gym.Env) -> np.ndarray:
        return np.array([env.unwrapped.expert_move()], dtype=np.float32)

    def to_label(self, action: np.ndarray) -> Any:
        if self.discrete:
            return int(np.rint(action[0])) + 1
        return np.asarray(action[:1], dtype=np.float32)

    def combine(self, label: Any, action: np.ndarray) -> np.ndarray:
        if self.discrete:
            return np.array([int(label) - 1], dtype=np.float32)
        return np.asarray(label, dtype=np.float32).reshape(1)

    def is_success(self, env: gym.Env) -> bool:
        return not env.unwrapped.crashed()


#: A small network for 16x16 images (fast on one core); also the task's default.
TOY_ARCH = CorridorTask.policy_arch


class RunCorridorTask(CorridorTask):
    """The discrete corridor as a task the run pipeline can build: ``make_task(name,
    max_episode_steps=...)`` (what a run's config passes) sets the road's length."""

    def __init__(self, *, max_episode_steps: int = 30):
        super().__init__(discrete=True)
        self.max_episode_steps = max_episode_steps


TINY_PRESETS = """\
presets:
  tiny:
    max_episode_steps: 12
    pistar:
      seeds: 0-1
      eval_seeds: 100-100
      min_success: 0.0
      dagger_rounds: 1
      bc: {lr: 3.0e-3, batch_size: 16, epochs: 1}
    pairs:
      seeds: 200-203
      dagger_rounds: 1
      keep: all
      bc: {lr: 1.0e-2, batch_size: 10, epochs: 1, head_only: true}
      dagger_bc: {lr: 1.0e-2, batch_size: 10, epochs: 1, head_only: true}
    evaluate: {seeds: 300-301, methods: [dm], oneshot: false}
"""
"""A presets file for :class:`RunCorridorTask` runs: a two-seed pi*, four pairs, two evaluation seeds."""


@dataclass(frozen=True)
class MirrorVariation(Variation):
    """The corridor family's variation: half of the seeds mirror the lateral move."""

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        return {"mirror": -1.0 if rng.random() < 0.5 else 1.0}

    def apply(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        return action * variation["mirror"]

    def compensate(self, variation: dict[str, float], action: np.ndarray) -> np.ndarray:
        return action * variation["mirror"]

    def size(self, variation: dict[str, float]) -> float:
        return (1.0 - variation["mirror"]) / 2.0


class CorridorFamily(FamilyTask):
    """The discrete corridor as a task family (docs/custom_task.md, "Your own task family")."""

    def __init__(self, *, max_episode_steps: int = 30):
        super().__init__(
            RunCorridorTask(max_episode_steps=max_episode_steps), MirrorVariation(), name="corridor-family"
        )
