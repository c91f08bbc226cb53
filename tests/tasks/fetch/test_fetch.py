"""The Fetch pixel env, its learner env and the fetch task."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

pytest.importorskip("gymnasium_robotics")
mujoco = pytest.importorskip("mujoco")

import gymnasium as gym  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

import metadagger  # noqa: E402
from metadagger.tasks.fetch.env import (  # noqa: E402
    UPSTREAM_ID,
    FetchPickAndPlacePixels,
    bench_fetch_env,
    fetch_is_success,
    read_fetch_state,
)
from metadagger.tasks.fetch.task import FetchTask, expert_success  # noqa: E402

PIXELS_ID = "metadagger/FetchPickAndPlacePixels-v0"
XYZ_ID = "metadagger/FetchPickAndPlaceXYZ-v0"


@pytest.fixture(scope="module")
def env():
    env = FetchPickAndPlacePixels()
    yield env
    env.close()


def _changed_pixels(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a.astype(int) - b.astype(int)).sum(-1) > 30).sum())


def test_check_env_pixels():
    env = gym.make(PIXELS_ID)
    try:
        check_env(env.unwrapped)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", [XYZ_ID, "metadagger/FetchPickAndPlaceXYZFamily-v0"])
def test_check_env_xyz(env_id):
    env = gym.make(env_id)
    try:
        with warnings.catch_warnings():
            # The learner env is a wrapper by design; check_env only warns about that.
            warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
            check_env(env)
    finally:
        env.close()


def test_spaces_and_time_limit():
    env = gym.make(PIXELS_ID)
    try:
        assert env.observation_space == gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
        assert env.action_space.shape == (4,)
        assert env.spec.max_episode_steps == 50
        obs, _ = env.reset(seed=0)
        for step in range(50):
            obs, _, terminated, truncated, info = env.step(np.zeros(4, np.float32))
            assert not terminated
            assert truncated == (step == 49)
        assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
        assert isinstance(info["is_success"], bool)
    finally:
        env.close()


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_cube_and_target_are_visible(env, seed):
    obs, _ = env.reset(seed=seed)
    fetch = env.fetch
    joint = mujoco.mj_name2id(fetch.model, mujoco.mjtObj.mjOBJ_JOINT, "object0:joint")
    adr = fetch.model.jnt_qposadr[joint]
    saved = fetch.data.qpos.copy()
    fetch.data.qpos[adr : adr + 2] = [3.0, 3.0]  # far off the table, out of view
    mujoco.mj_forward(fetch.model, fetch.data)
    without_cube = fetch.render()
    fetch.data.qpos[:] = saved
    mujoco.mj_forward(fetch.model, fetch.data)
    assert _changed_pixels(obs, without_cube) >= 15

    goal = fetch.goal.copy()
    fetch.goal[:] = [3.0, 3.0, 0.0]
    without_target = fetch.render()
    fetch.goal[:] = goal
    assert _changed_pixels(obs, without_target) >= 5


@pytest.mark.parametrize("seed", [0, 1, 2, 5])
def test_goal_at_cube_height_and_upstream_layout(env, seed):
    env.reset(seed=seed)
    state = env.state()
    assert state.goal[2] == pytest.approx(state.object_pos[2])
    upstream = gym.make(UPSTREAM_ID).unwrapped
    upstream.reset(seed=seed)
    ref = read_fetch_state(upstream)
    upstream.close()
    np.testing.assert_allclose(state.object_pos, ref.object_pos)
    np.testing.assert_allclose(state.goal[:2], ref.goal[:2])
    # The target site is drawn at the lowered goal, not upstream's.
    site = mujoco.mj_name2id(env.fetch.model, mujoco.mjtObj.mjOBJ_SITE, "target0")
    np.testing.assert_allclose(env.fetch.data.site_xpos[site], state.goal, atol=1e-6)


def test_reset_is_deterministic(env):
    other = FetchPickAndPlacePixels()
    try:
        a, _ = env.reset(seed=11)
        b, _ = other.reset(seed=11)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(env.state().goal, other.state().goal)
        action = np.array([0.5, -0.3, -0.2, 1.0], np.float32)
        np.testing.assert_array_equal(env.step(action)[0], other.step(action)[0])
        c, _ = other.reset(seed=12)
        assert not np.array_equal(a, c)
    finally:
        other.close()


def test_env_renders_its_own_frames_after_another_env_closed(env):
    """Closing another env leaves no OpenGL context current; ours must still render its scene
    (it used to come out black, which failed every rollout in an env reused across envs)."""
    action = np.array([0.3, 0.2, -0.1, 1.0], np.float32)
    before = [env.reset(seed=21)[0], env.step(action)[0]]
    other = FetchPickAndPlacePixels()
    other.reset(seed=22)
    other.close()
    after = [env.reset(seed=21)[0], env.step(action)[0]]
    assert before[0].mean() > 50  # a real frame, not a black one
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)


def test_state_and_success_rule(env):
    env.reset(seed=4)
    state = env.state()
    assert -0.01 <= state.gripper_opening <= 0.11
    assert not fetch_is_success(env)
    env.fetch.goal[:] = state.object_pos
    assert fetch_is_success(env)
    with pytest.raises(TypeError, match="Fetch env"):
        read_fetch_state(gym.make("CartPole-v1"))


def test_task_interface():
    task = metadagger.make_task("fetch")
    assert isinstance(task, FetchTask)
    assert task.learner_env_id == XYZ_ID and task.max_episode_steps == 50
    assert task.learner_action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    assert not task.is_discrete and task.label_dim() == 3
    action = np.array([0.1, -0.2, 0.3, -1.0], np.float32)
    label = task.to_label(action)
    assert label.dtype == np.float32 and label.shape == (3,)
    np.testing.assert_array_equal(task.combine(np.array([2.0, 0.0, -0.5]), action), [1.0, 0.0, -0.5, -1.0])
    with pytest.raises(ValueError, match="shape \\(3,\\)"):
        task.combine(np.zeros(4), action)


def test_learner_env_labels_and_success():
    env = gym.make(XYZ_ID)
    try:
        obs, info = env.reset(seed=0)
        assert obs.shape == (64, 64, 3)
        assert info["expert_label"].shape == (3,) and info["expert_action"].shape == (4,)
        assert env.action_space.shape == (3,)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(np.zeros(3, np.float32))
            done = terminated or truncated
        assert info["is_success"] is False  # standing still never moves the cube
    finally:
        env.close()


def test_expert_succeeds_on_a_few_seeds():
    assert expert_success(seeds=[0, 1, 2]) == [True, True, True]


def test_bench_reports_rates():
    result = bench_fetch_env(seeds=[0], steps=5)
    assert result["steps"] == 5 and result["steps_per_second"] > 0 and result["image_size"] == 64
    with pytest.raises(ValueError, match="steps"):
        bench_fetch_env(seeds=[0], steps=0)


_AFTER_SDL = """
import os
from metadagger.tasks.fetch.env import FetchPickAndPlacePixels
env = FetchPickAndPlacePixels(); env.reset(seed=0); env.close()
import pygame  # what check_env on upstream CarRacing does with render_mode="human", headless
pygame.display.init(); pygame.display.set_mode((8, 8)); pygame.quit()
env = FetchPickAndPlacePixels(); obs, _ = env.reset(seed=0); env.close()
print(obs.shape)
"""


def test_new_envs_render_after_sdl_terminated_the_egl_display():
    pytest.importorskip("pygame")
    # In a child process: SDL's quit kills the EGL contexts of envs that are still open.
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen"}
    result = subprocess.run([sys.executable, "-c", _AFTER_SDL], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "(64, 64, 3)" in result.stdout
