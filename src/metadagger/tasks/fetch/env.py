"""FetchPickAndPlace from pixels: the base env of the ``fetch`` task (paper section 4.2).

The rendering backend must be chosen before :mod:`mujoco` is first imported, hence the
``MUJOCO_GL`` default at the top of this module: ``egl`` renders headless, on the GPU where there
is one and with Mesa's software rasteriser (llvmpipe) where there is not. Set ``MUJOCO_GL``
before importing metadagger to choose another backend.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib  # noqa: E402
import io  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import Any, Sequence  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

# gymnasium-robotics prints a notice about its Adroit envs' rewards to stderr on import, in every
# worker process; it does not concern Fetch, so it is kept off the console.
with contextlib.redirect_stderr(io.StringIO()):
    import gymnasium_robotics  # noqa: E402

gym.register_envs(gymnasium_robotics)

UPSTREAM_ID = "FetchPickAndPlace-v4"
#: A free camera in front of the table, facing the robot, 40 degrees down, with a narrow field of
#: view (``fovy``, degrees) so the gripper hides little of the table. Over seeds 0-99 the cube
#: covers at least 26 pixels of the 64x64 start image (median 80) and is never hidden; steeper
#: views lose it behind the gripper in up to 1 start in 5. The target is hidden (under the
#: gripper) in 2 starts of 100.
DEFAULT_CAMERA: dict[str, Any] = {
    "distance": 0.9,
    "azimuth": 180.0,
    "elevation": -40.0,
    "lookat": np.array([1.34, 0.75, 0.45]),
    "fovy": 28.0,
}


@dataclass(frozen=True)
class FetchState:
    """The simulator state the expert reads (world frame, metres).

    Attributes:
        grip_pos: Position of the grip site between the fingers, shape (3,).
        object_pos: Centre of the cube, shape (3,).
        goal: Target position of the cube's centre, shape (3,).
        gripper_opening: Sum of the two finger joints: about 0.1 fully open, 0.05 round the cube,
            0 closed (a little below 0 when the fingers squeeze).
    """

    grip_pos: np.ndarray
    object_pos: np.ndarray
    goal: np.ndarray
    gripper_opening: float

    def __post_init__(self) -> None:
        for name in ("grip_pos", "object_pos", "goal"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (3,):
                raise ValueError(f"FetchState.{name} must have shape (3,), got {value.shape}")
            object.__setattr__(self, name, value)
        if not np.isfinite(self.gripper_opening):
            raise ValueError(f"FetchState.gripper_opening must be finite, got {self.gripper_opening}")


def upstream_fetch_env(env: gym.Env) -> Any:
    """The gymnasium-robotics Fetch env behind ``env`` (ours, the upstream one, or a wrapper of either)."""
    base = env.unwrapped
    fetch = getattr(base, "fetch", base)
    if not hasattr(fetch, "generate_mujoco_observations") or not hasattr(fetch, "goal"):
        raise TypeError(f"expected a Fetch env (metadagger or gymnasium-robotics), got {type(base).__name__}")
    return fetch


def read_fetch_state(env: gym.Env) -> FetchState:
    """The current :class:`FetchState` of a Fetch env (ours, the upstream one, or a wrapper of either).

    It reads the grip site, the cube and the two finger joints and nothing else: the values
    upstream's ``generate_mujoco_observations`` returns for them, without its rotations and
    velocities, at a tenth of its cost (tests/tasks/fetch: bit-equal on every step of noisy episodes).
    """
    fetch = upstream_fetch_env(env)
    model, data, utils = getattr(fetch, "model", None), getattr(fetch, "data", None), getattr(fetch, "_utils", None)
    if model is None or data is None or utils is None:  # not the mujoco bindings' env: upstream's whole reading
        grip_pos, object_pos, _, finger_qpos, *_ = fetch.generate_mujoco_observations()
    else:
        grip_pos = utils.get_site_xpos(model, data, "robot0:grip")
        object_pos = utils.get_site_xpos(model, data, "object0")
        # upstream's gripper state: the last two of the robot's joints, stacked and squeezed as it does
        fingers = [name for name in fetch._model_names.joint_names if name.startswith("robot")][-2:]
        finger_qpos = np.squeeze(np.array([utils.get_joint_qpos(model, data, name) for name in fingers]))
    return FetchState(
        grip_pos=grip_pos.copy(),
        object_pos=np.ravel(object_pos).copy(),
        goal=np.asarray(fetch.goal, dtype=np.float64).copy(),
        gripper_opening=float(np.sum(finger_qpos)),
    )


def lower_goal_to_object(env: gym.Env) -> None:
    """Put the goal at the cube's height (paper section 4.2); call right after an upstream reset."""
    fetch = upstream_fetch_env(env)
    fetch.goal[2] = read_fetch_state(fetch).object_pos[2]


def fetch_is_success(env: gym.Env) -> bool:
    """Upstream's success rule on the current state: the cube's centre within the distance threshold of the goal."""
    fetch = upstream_fetch_env(env)
    state = read_fetch_state(env)
    return bool(np.linalg.norm(state.object_pos - state.goal) < fetch.distance_threshold)


def _ensure_egl_display() -> None:
    """Initialise mujoco's EGL display again if something terminated it.

    EGL displays are shared per process, and SDL's offscreen video driver terminates the display
    when it quits (e.g. after a pygame window: upstream CarRacing's ``render_mode="human"``).
    Every env created afterwards then fails with ``EGL_NOT_INITIALIZED``. Initialising an
    initialised display does nothing.
    """
    egl = sys.modules.get("mujoco.egl")  # mujoco creates its display with the first context
    if egl is None or egl.EGL_DISPLAY is None:
        return
    egl.EGL.eglInitialize(egl.EGL_DISPLAY, None, None)


class FetchPickAndPlacePixels(gym.Env[np.ndarray, np.ndarray]):
    """FetchPickAndPlace seen through a 64x64 camera, with the goal at the cube's height.

    ## Description
    gymnasium-robotics' ``FetchPickAndPlace-v4``: a Fetch arm must move a cube to a target. As in
    the paper (section 4.2) the observation is an image, not the state vector, and the goal is
    confined to the object's height (upstream puts it in the air half of the time).

    ## Action Space
    ``Box(-1, 1, (4,), float32)`` as upstream: x, y, z displacement of the gripper (at most 0.05 m
    per step) and the finger command (+1 opens, -1 closes).

    ## Observation Space
    ``Box(0, 255, (64, 64, 3), uint8)``: an RGB image from a free camera over the table
    (:data:`DEFAULT_CAMERA`) showing the gripper, the cube (dark) and the target (red sphere).

    ## Rewards
    Upstream's sparse reward: 0 when the cube is within 5 cm of the goal, else -1.

    ## Starting State
    Upstream's: the gripper above the table centre, the cube uniformly within 15 cm of it (at
    least 10 cm away), the goal uniformly within 15 cm, then lowered to the cube's height.

    ## Episode Termination
    Never terminates; truncated after 50 steps by the registered time limit.
    ``info["is_success"]`` holds upstream's success flag after every step.

    ## Arguments
    ``render_mode``: ``None`` or ``"rgb_array"`` (the observation frame). ``camera``: mujoco free
    camera settings (distance, azimuth, elevation, lookat) and ``fovy``; defaults to
    :data:`DEFAULT_CAMERA`.
    ``image_size``: side of the square image in pixels.

    The simulator state for the expert is :meth:`state` (see :func:`read_fetch_state`).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        *,
        render_mode: str | None = None,
        camera: dict[str, Any] | None = None,
        image_size: int = 64,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if image_size < 16:
            raise ValueError(f"image_size must be at least 16 pixels, got {image_size}")
        self.render_mode = render_mode
        _ensure_egl_display()
        camera = dict(DEFAULT_CAMERA if camera is None else camera)
        # The field of view is the model's, not the free camera's (mjvCamera has no fovy).
        fovy = camera.pop("fovy", None)
        self.fetch = gym.make(
            UPSTREAM_ID,
            render_mode="rgb_array",
            width=image_size,
            height=image_size,
            default_camera_config=camera,
        ).unwrapped
        if fovy is not None:
            self.fetch.model.vis.global_.fovy = float(fovy)
        # Multisample anti-aliasing halves the frame rate of software rendering (docs/fetch.md).
        self.fetch.model.vis.quality.offsamples = 0
        self.action_space = self.fetch.action_space
        self.observation_space = gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
        self._frame: np.ndarray | None = None
        self._closed = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        # One generator for the whole env: upstream samples the cube and goal from ours, so a
        # given seed lays out the same scene as upstream's reset(seed=seed).
        self.fetch.np_random = self.np_random
        self.fetch.reset()
        lower_goal_to_object(self.fetch)
        # upstream's reset observation still carries the old goal; ours is rendered after the
        # change, and rendering moves the target site to the new goal.
        return self._observe(), {"is_success": fetch_is_success(self.fetch)}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        _, reward, terminated, truncated, info = self.fetch.step(np.asarray(action, dtype=np.float32))
        info = {"is_success": bool(info["is_success"])}
        return self._observe(), float(reward), bool(terminated), bool(truncated), info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called with render_mode=None; pass render_mode='rgb_array'")
            return None
        return (self._frame if self._frame is not None else self._observe()).copy()

    def state(self) -> FetchState:
        """The simulator state (gripper, cube, goal, finger opening) for the expert."""
        return read_fetch_state(self.fetch)

    def close(self) -> None:
        if not self._closed:
            self.fetch.close()
            self._closed = True

    def _observe(self) -> np.ndarray:
        # Upstream renders into whichever OpenGL context is current. Creating another env makes
        # its context current, and closing that env leaves none, so without this the frames of
        # an env used after another one was created (and closed) are someone else's or black.
        viewer = self.fetch.mujoco_renderer.viewer
        if viewer is not None:
            viewer.make_context_current()
        self._frame = np.ascontiguousarray(self.fetch.render(), dtype=np.uint8)
        return self._frame.copy()


def bench_fetch_env(*, seeds: Sequence[int], steps: int) -> dict[str, Any]:
    """Frames per second of the pixel env: ``steps`` uniformly random actions per seed.

    Every step renders one observation, so steps per second is frames per second. The first
    reset, which creates the OpenGL context, is timed on its own and left out of the rates.

    Args:
        seeds: Episode seeds; the action sampler is seeded with each too.
        steps: Steps per seed (an episode is 50 steps; this benchmark ignores the time limit).

    Returns:
        A JSON-ready dict with the totals and rates.
    """
    if len(seeds) == 0 or steps <= 0:
        raise ValueError(
            f"bench_fetch_env needs at least one seed and steps > 0, got {len(seeds)} seeds and steps={steps}"
        )
    env = FetchPickAndPlacePixels()
    try:
        start = time.perf_counter()
        env.reset(seed=int(seeds[0]))
        first_reset_s = time.perf_counter() - start
        reset_s = step_s = 0.0
        for seed in seeds:
            start = time.perf_counter()
            env.reset(seed=int(seed))
            reset_s += time.perf_counter() - start
            env.action_space.seed(int(seed))
            actions = [env.action_space.sample() for _ in range(steps)]
            start = time.perf_counter()
            for action in actions:
                env.step(action)
            step_s += time.perf_counter() - start
    finally:
        env.close()
    total = len(seeds) * steps
    return {
        "env": "metadagger/FetchPickAndPlacePixels-v0",
        "mujoco_gl": os.environ.get("MUJOCO_GL", ""),
        "image_size": int(env.observation_space.shape[0]),
        "seeds": len(seeds),
        "steps": total,
        "step_seconds": step_s,
        "steps_per_second": total / step_s,
        "resets_per_second": len(seeds) / reset_s,
        "first_reset_seconds": first_reset_s,
    }
