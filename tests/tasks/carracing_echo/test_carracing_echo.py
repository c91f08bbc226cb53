"""carracing-echo: CarRacing whose frame marks the steering executed on the step before."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from metadagger.errors import UserError
from metadagger.imitation.rollouts import rollout
from metadagger.tasks import LearnerEnv, make_task, register_envs
from metadagger.tasks.carracing.expert import PIDExpert
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask
from metadagger.tasks.carracing_echo.task import MARK_WIDTH, CarRacingEchoTask, SteeringEcho
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
    for bad in (-1, 33, 2.5, True):
        with pytest.raises(UserError, match=rf"echo_rows must be an integer from 0 \(no band\) to 32, got {bad!r}"):
            make_task("carracing-echo", echo_rows=bad)
    faulty = make_task("carracing-echo", echo_rows=0, fault_rate=0.01, fault_steps=10, fault_offset=0.15)
    assert task_stamp(faulty)["task_options"] == {
        "echo_rows": 0,
        "fault_rate": 0.01,
        "fault_steps": 10,
        "fault_offset": 0.15,
    }
    for key, bad in (("fault_rate", 1.5), ("fault_steps", 0), ("fault_offset", -0.1), ("fault_rate", "high")):
        with pytest.raises(UserError, match=f"{key} must be"):
            make_task("carracing-echo", **{key: bad})


def _offsets_and_labels(task: CarRacingEchoTask, seed: int, hold: int | None) -> tuple[list[float], list[float]]:
    """Each step's fault offset, and how far the executed steering (the expert's class plus the fault)
    lies from what the PID expert wants; the expert drives, or a learner holding class ``hold``."""
    env = task.make_env()
    _, info = env.reset(seed=seed)
    offsets, misses, done = [], [], False
    while not done:
        offset = float(env.env.get_wrapper_attr("next_offset"))
        wanted = float(np.clip(PIDExpert()(env.env)[0], -0.4, 0.4))
        if abs(wanted - offset) <= 0.4:  # a fault the expert can steer against within the wheel's range
            misses.append(abs(STEERING_VALUES[info["expert_label"]] + offset - wanted))
        offsets.append(offset)
        _, _, terminated, truncated, info = env.step(info["expert_label"] if hold is None else hold)
        done = terminated or truncated
    env.close()
    return offsets, misses


def test_faults_follow_the_reset_seed_and_the_expert_steers_against_each_one():
    """The schedule is the seed's whoever drives; the expert's label, with the fault added, executes
    the steering it wants (to half a class), so the fault never moves the expert off its line."""
    task = CarRacingEchoTask(max_episode_steps=300, echo_rows=0, fault_rate=0.02, fault_steps=10, fault_offset=0.15)
    expert, misses = _offsets_and_labels(task, 1003, hold=None)
    learner, _ = _offsets_and_labels(task, 1003, hold=12)
    again, _ = _offsets_and_labels(task, 1003, hold=None)
    other, _ = _offsets_and_labels(task, 1004, hold=None)
    assert expert == learner == again and expert != other
    assert set(expert) == {0.0, 0.15, -0.15}
    assert max(misses) <= 0.5 * (STEERING_VALUES[1] - STEERING_VALUES[0]) + 1e-6
    bursts = np.flatnonzero(np.diff(np.abs(expert)) > 0)
    assert all(np.count_nonzero(expert[start + 1 : start + 11]) == 10 for start in bursts[:-1])


def test_a_learner_blind_to_the_faults_leaves_the_line_the_expert_keeps():
    """The PID expert's own steering without the fault's counter-steer (the best a learner that cannot
    see the fault can do) drifts away from where the expert, on the same seed, drives."""
    task = CarRacingEchoTask(max_episode_steps=300, echo_rows=0, fault_rate=0.02, fault_steps=10, fault_offset=0.15)
    paths = []
    for blind in (False, True):
        env = task.make_env()
        _, info = env.reset(seed=1003)
        path = []
        for _ in range(300):
            label = task.to_label(PIDExpert()(env.env)) if blind else info["expert_label"]
            info = env.step(label)[4]
            path.append(np.array(env.unwrapped.car.hull.position))
        paths.append(np.array(path))
        env.close()
    apart = np.linalg.norm(paths[0] - paths[1], axis=1)
    assert apart.max() > 5.0, apart.max()
