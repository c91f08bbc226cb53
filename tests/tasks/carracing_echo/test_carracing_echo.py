"""carracing-echo: CarRacing whose frame marks the steering executed on the step before."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from metadagger.errors import UserError
from metadagger.imitation.rollouts import rollout
from metadagger.tasks import LearnerEnv, make_task, register_envs
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask
from metadagger.tasks.carracing_echo.task import MARK_WIDTH, SteeringEcho
from metadagger.tasks.identity import task_stamp


def test_the_registered_env_passes_check_env():
    register_envs()
    env = gym.make("metadagger/CarRacingEcho-v0", max_episode_steps=20)
    while not isinstance(env, LearnerEnv):  # peel the checker wrappers gym.make adds
        env = env.env
    assert isinstance(env.env, SteeringEcho)
    check_env(env, skip_render_check=True)
    env.close()


def test_the_band_marks_the_class_executed_on_the_step_before_and_nothing_after_a_reset():
    task = make_task("carracing-echo", max_episode_steps=30, echo_rows=5)
    env = task.make_env()
    obs, _ = env.reset(seed=1000)
    assert (obs[:5] == 0).all() and (obs[5:] != 0).any()
    for label in (0, 7, 19):
        obs = env.step(label)[0]
        marked = np.flatnonzero((obs[:5] == 255).all(axis=(0, 2)))
        left = round(label * (96 - MARK_WIDTH) / (len(STEERING_VALUES) - 1))
        assert marked.tolist() == list(range(left, left + MARK_WIDTH)), label
        assert (np.delete(obs[:5], marked, axis=1) == 0).all()
    env.close()


def test_the_expert_drives_as_on_plain_carracing_and_the_band_is_the_only_difference():
    """The expert reads the simulator, never the frame: its episode is CarRacing's, step for step."""
    echo = rollout(make_task("carracing-echo", max_episode_steps=120).make_env(), seed=1001, policy=None)
    plain = rollout(CarRacingTask(max_episode_steps=120).make_env(), seed=1001, policy=None)
    np.testing.assert_array_equal(echo.expert_labels, plain.expert_labels)
    np.testing.assert_array_equal(echo.obs[:, 6:], plain.obs[:, 6:])
    assert not np.array_equal(echo.obs[:, :6], plain.obs[:, :6])


def test_a_variant_is_its_own_task_in_every_stamp_and_a_bad_band_is_one_line():
    assert task_stamp(make_task("carracing-echo", echo_rows=3))["task_options"] == {"echo_rows": 3}
    assert task_stamp(make_task("carracing-echo"))["task_options"] == {"echo_rows": 6}
    assert "task_options" not in task_stamp(make_task("carracing"))
    for bad in (0, 33, 2.5, True):
        with pytest.raises(UserError, match=f"echo_rows must be an integer from 1 to 32, got {bad!r}"):
            make_task("carracing-echo", echo_rows=bad)
