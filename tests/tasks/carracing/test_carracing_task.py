"""The CarRacing task and the learner env ``metadagger/CarRacingSteer-v0``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import metadagger
from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask, make_steer_env


@pytest.fixture
def task() -> CarRacingTask:
    return metadagger.make_task("carracing")


def test_make_task_builds_the_carracing_task(task):
    assert isinstance(task, CarRacingTask)
    assert task.name == "carracing"
    assert task.learner_env_id == "metadagger/CarRacingSteer-v0"
    assert task.max_episode_steps == 1000
    assert task.learner_action_space == gym.spaces.Discrete(20)
    assert task.is_discrete and task.label_dim() == 20
    assert metadagger.make_task("carracing", max_episode_steps=50).max_episode_steps == 50


def test_unknown_task_is_a_user_error():
    with pytest.raises(UserError, match="unknown task 'carracer'"):
        metadagger.make_task("carracer")


@pytest.mark.parametrize("bad", [0, -5, 2.5, True])
def test_bad_max_episode_steps_is_a_user_error(bad):
    with pytest.raises(UserError, match="max_episode_steps"):
        CarRacingTask(max_episode_steps=bad)


def test_steering_values_cover_the_wheel_range():
    assert STEERING_VALUES.shape == (20,)
    assert np.all(np.diff(STEERING_VALUES) > 0)
    np.testing.assert_allclose(STEERING_VALUES, -STEERING_VALUES[::-1], atol=1e-7)
    assert STEERING_VALUES[0] == pytest.approx(-0.4) and STEERING_VALUES[-1] == pytest.approx(0.4)
    with pytest.raises(ValueError):
        STEERING_VALUES[0] = 0.0


def test_label_and_combine_round_trip(task, rng):
    for label in range(20):
        expert_action = np.array([rng.uniform(-1, 1), rng.uniform(0, 1), rng.uniform(0, 1)], dtype=np.float32)
        full = task.combine(label, expert_action)
        assert full.dtype == np.float32
        assert full[0] == STEERING_VALUES[label]
        np.testing.assert_array_equal(full[1:], expert_action[1:])  # gas and brake stay the expert's
        assert task.to_label(full) == label
        assert task.combine(np.int64(label), expert_action)[0] == full[0]


def test_to_label_snaps_to_the_nearest_value(task):
    assert task.to_label(np.array([-1.0, 0, 0])) == 0  # beyond the wheel limit: full lock
    assert task.to_label(np.array([1.0, 0, 0])) == 19
    assert task.to_label(np.array([0.01, 0, 0])) == 10  # just right of straight
    assert task.to_label(np.array([-0.01, 0, 0])) == 9


@pytest.mark.parametrize("label", [-1, 20, 3.5])
def test_combine_rejects_bad_labels(task, label):
    with pytest.raises(ValueError, match="steering label"):
        task.combine(label, np.zeros(3, dtype=np.float32))


def test_registered_learner_env_passes_check_env():
    env = gym.make("metadagger/CarRacingSteer-v0")
    while not isinstance(env, LearnerEnv):  # peel the checker wrappers gym.make adds
        env = env.env
    check_env(env, skip_render_check=True)
    env.close()


def test_make_steer_env_labels_every_observation():
    env = make_steer_env(max_episode_steps=5)
    assert env.action_space == gym.spaces.Discrete(20)
    _, info = env.reset(seed=4)
    assert 0 <= info["expert_label"] < 20
    for _ in range(5):
        _, _, terminated, truncated, info = env.step(info["expert_label"])
        assert isinstance(info["expert_label"], int)
    assert truncated and not terminated
    assert info["is_success"] is False  # five steps are no lap
    env.close()


def test_same_seed_same_episode(task):
    runs = []
    for _ in range(2):
        env = task.make_env(seed=7)
        obs, info = env.reset(seed=7)
        frames = [obs]
        for _ in range(20):
            obs, *_, info = env.step(info["expert_label"])
            frames.append(obs)
        runs.append(np.stack(frames))
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_is_success_needs_every_tile(task):
    env = task.make_env(seed=0)
    base = env.unwrapped
    assert not task.is_success(env)
    base.tile_visited_count = len(base.track)
    assert task.is_success(env)
    env.close()
