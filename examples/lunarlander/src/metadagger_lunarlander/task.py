"""The ``lunarlander`` tasks: Gymnasium's LunarLander-v3 (discrete) from pixels.

The learner sees a small stack of grey images of the rendered scene. The expert is Gymnasium's
own heuristic controller (``gymnasium.envs.box2d.lunar_lander.heuristic``), which reads the
8-dimensional state vector that :class:`LanderPixels` keeps beside the image. Upstream's actions
are 0 (nothing), 1 (left engine), 2 (main engine) and 3 (right engine).

- ``lunarlander`` (:class:`LunarLanderTask`): the learner fires the main engine or not; when it
  does not, the expert's side engines keep the lander upright (as CarRacing's learner steers and
  its expert drives gas and brake).
- ``lunarlander-all`` (:class:`LunarLanderAllEnginesTask`): the learner chooses all four actions.
  Its pi* does not land (README.md, "Making pi* work"); it is kept to show that.

Success: the lander comes to rest without crashing (the episode ends with the env's landing bonus).
"""

from __future__ import annotations

from collections import deque
from typing import Any, SupportsFloat

import cv2
import gymnasium as gym
import numpy as np
from gymnasium.envs.box2d.lunar_lander import LunarLander, heuristic

from metadagger.tasks import Task

#: Height and width of the learner's image (the scene is 400 x 600 pixels: the same aspect).
HEIGHT, WIDTH = 64, 96
#: Simulator steps per learner step (the action is repeated; the heuristic still lands 95 of
#: seeds 10000-10099 this way, 96 acting on every step).
FRAME_SKIP = 3
#: Upstream's discrete actions: the main engine, and the left and right side engines.
MAIN_ENGINE, SIDE_ENGINES = 2, (1, 3)


class LanderPixels(gym.Wrapper):
    """LunarLander observed from pixels, one learner step every ``frame_skip`` simulator steps.

    ``step(action)`` repeats ``action`` for ``frame_skip`` simulator steps (fewer when the
    episode ends first), summing the rewards. The observation, ``Box(0, 255, (HEIGHT, WIDTH, 3),
    uint8)``, holds three grey images of the scene (downsampled by area averaging): now, one
    learner step ago and two learner steps ago (the first image repeated after a reset). One image
    shows where the lander is; the three show how it moves, which the expert's decisions depend
    on. The engines' flame particles are left out of the images: they are decoration (they collide
    with the ground only) and would show the learner its own last actions.

    The state vector of the last reset or step is kept as :attr:`lander_state` (read it with
    ``env.get_wrapper_attr("lander_state")``): LunarLander keeps none on ``env.unwrapped``.

    Args:
        env: a LunarLander with ``render_mode="rgb_array"``.
        frame_skip: simulator steps per ``step``.
    """

    def __init__(self, env: gym.Env, *, frame_skip: int = FRAME_SKIP):
        super().__init__(env)
        if env.render_mode != "rgb_array":
            raise ValueError(f"LanderPixels needs render_mode='rgb_array', got {env.render_mode!r}")
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, int) or frame_skip < 1:
            raise ValueError(f"frame_skip must be an integer >= 1, got {frame_skip!r}")
        self.frame_skip = frame_skip
        self.observation_space = gym.spaces.Box(0, 255, (HEIGHT, WIDTH, 3), np.uint8)
        self.lander_state = np.zeros(8, np.float32)
        self._frames: deque[np.ndarray] = deque(maxlen=3)

    def _grey(self) -> np.ndarray:
        self.env.unwrapped._clean_particles(True)  # no flames in the image (see the class docstring)
        scene = cv2.resize(self.env.render(), (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(scene, cv2.COLOR_RGB2GRAY)

    def _observation(self) -> np.ndarray:
        return np.stack([self._frames[2], self._frames[1], self._frames[0]], axis=-1)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        state, info = self.env.reset(seed=seed, options=options)
        self.lander_state = np.asarray(state, np.float32)
        self._frames.extend([self._grey()] * 3)
        return self._observation(), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        total = 0.0
        for _ in range(self.frame_skip):
            state, reward, terminated, truncated, info = self.env.step(action)
            total += float(reward)
            if terminated or truncated:
                break
        self.lander_state = np.asarray(state, np.float32)
        self._frames.append(self._grey())
        return self._observation(), total, terminated, truncated, info


class LunarLanderTask(Task):
    """LunarLander-v3 (discrete) from pixels, the learner on the main engine (module docstring).

    Args:
        max_episode_steps: step limit of one episode, in learner steps of ``FRAME_SKIP``
            simulator steps each (the heuristic lands within 100 on nearly every seed).
    """

    name = "lunarlander"
    learner_env_id = "LunarLander-v3"  # informational: the upstream env behind the pixels
    #: A keypoint trunk (README.md, "Making pi* work"): three 3x3 convolutions keeping 32 x 48
    #: maps, a spatial softmax (the expected x, y of each of 16 maps), then 128 and 64 units; the
    #: head maps 64 features to the 2 action logits (130 weights).
    policy_arch = {
        "conv_channels": (8, 16, 16),
        "kernel_sizes": (3, 3, 3),
        "strides": (2, 1, 1),
        "hidden": (128, 64),
        "spatial_softmax": True,
    }

    def __init__(self, *, max_episode_steps: int = 200):
        if (
            isinstance(max_episode_steps, bool)
            or not isinstance(max_episode_steps, (int, np.integer))
            or max_episode_steps < 1
        ):
            raise ValueError(f"max_episode_steps must be a positive integer, got {max_episode_steps!r}")
        self.max_episode_steps = int(max_episode_steps)

    @property
    def learner_action_space(self) -> gym.spaces.Discrete:
        """``Discrete(2)``: 1 fires the main engine, 0 leaves the step to the expert's side engines."""
        return gym.spaces.Discrete(2)

    def make_base_env(self, **kwargs: Any) -> LanderPixels:
        """A :class:`LanderPixels` around a new ``LunarLander(render_mode="rgb_array", **kwargs)``."""
        return LanderPixels(LunarLander(render_mode="rgb_array", **kwargs))

    def expert(self, env: gym.Env) -> np.ndarray:
        """Gymnasium's heuristic on the last state vector: upstream's action (0 nothing, 1 left
        engine, 2 main engine, 3 right engine) as a one-element float32 array."""
        return np.array([heuristic(env, env.get_wrapper_attr("lander_state"))], np.float32)

    def to_label(self, action: np.ndarray) -> int:
        """The learner's part of an upstream action: 1 for the main engine, else 0."""
        return int(int(np.asarray(action).reshape(-1)[0]) == MAIN_ENGINE)

    def combine(self, label: Any, action: np.ndarray) -> int:
        """The main engine where the learner fires it; else the expert's side engine, if it fires
        one, or nothing."""
        index = int(label)
        if index != label or index not in (0, 1):
            raise ValueError(f"a lunarlander label must be 0 or 1, got {label!r}")
        if index == 1:
            return MAIN_ENGINE
        upstream = int(np.asarray(action).reshape(-1)[0])
        return upstream if upstream in SIDE_ENGINES else 0

    def is_success(self, env: gym.Env) -> bool:
        """Landed: the lander is at rest (the env ended the episode with its +100 landing bonus),
        its body never touched the ground and it is within the screen."""
        lander = env.unwrapped
        return bool(
            not lander.lander.awake
            and not lander.game_over
            and abs(float(env.get_wrapper_attr("lander_state")[0])) < 1.0
        )


class LunarLanderAllEnginesTask(LunarLanderTask):
    """LunarLander-v3 (discrete) from pixels, the learner on all four actions (module docstring)."""

    name = "lunarlander-all"

    @property
    def learner_action_space(self) -> gym.spaces.Discrete:
        """``Discrete(4)``: upstream's actions."""
        return gym.spaces.Discrete(4)

    def to_label(self, action: np.ndarray) -> int:
        """Upstream's action as a class index."""
        return int(np.asarray(action).reshape(-1)[0])

    def combine(self, label: Any, action: np.ndarray) -> int:
        """The learner's label is the whole action."""
        index = int(label)
        if index != label or not 0 <= index < 4:
            raise ValueError(f"a lunarlander-all label must be an integer in [0, 3], got {label!r}")
        return index
