"""The Fetch family: a rotated, scaled horizontal displacement per seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("gymnasium_robotics")
pytest.importorskip("mujoco")

import gymnasium as gym  # noqa: E402

from metadagger.errors import UserError  # noqa: E402
from metadagger.imitation.rollouts import rollout  # noqa: E402
from metadagger.tasks import make_task  # noqa: E402
from metadagger.tasks.fetch.env import read_fetch_state  # noqa: E402
from metadagger.tasks.fetch.family import DisplacementVariation, FetchFamily  # noqa: E402
from metadagger.tasks.fetch.task import FetchTask  # noqa: E402

FAMILY_ID = "metadagger/FetchPickAndPlaceXYZFamily-v0"
#: A pair-range seed whose arm is rotated by about 94 degrees (scale 1.34); the expert solves it.
ROTATED_SEED = 1000


@pytest.fixture(scope="module")
def task() -> FetchFamily:
    return FetchFamily()


def test_registered(task):
    made = make_task("fetch-family")
    assert isinstance(made, FetchFamily)
    assert made.name == "fetch-family" and made.learner_env_id == FAMILY_ID
    assert isinstance(made.pistar_task(), FetchTask)
    assert made.max_episode_steps == 50
    assert made.learner_action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)


def test_variation_is_a_pure_function_of_the_seed(task):
    seeds = range(1000, 1040)
    draws = [task.variation_of(s) for s in seeds]
    assert draws == [FetchFamily().variation_of(s) for s in seeds]
    assert len({(d["theta"], d["scale"]) for d in draws}) == len(draws)
    for d in draws:
        assert -math.pi <= d["theta"] <= math.pi and 1.0 <= d["scale"] <= 1.5
    # the whole circle is used: some seeds turn the arm round by more than a right angle
    assert any(abs(d["theta"]) > math.pi / 2 for d in draws)
    assert any(abs(d["theta"]) < math.pi / 2 for d in draws)


def test_distribution_follows_the_parameters():
    variation = DisplacementVariation(max_rotation=0.5, scale_range=(2.0, 2.0))
    for seed in range(20):
        d = variation.draw(seed)
        assert abs(d["theta"]) <= 0.5 and d["scale"] == pytest.approx(2.0)
    nominal = DisplacementVariation(max_rotation=0.0, scale_range=(1.0, 1.0))
    d = nominal.draw(3)
    assert d == {"theta": 0.0, "scale": 1.0} and nominal.size(d) == 0.0
    action = np.array([0.3, -0.7, 0.2, -1.0], np.float32)
    np.testing.assert_array_equal(nominal.apply(d, action), action)


def test_apply_rotates_scales_and_clips_xy_only():
    variation = DisplacementVariation()
    quarter = {"theta": math.pi / 2, "scale": 1.0}
    np.testing.assert_allclose(
        variation.apply(quarter, np.array([0.5, 0.0, 0.3, 1.0])), [0.0, 0.5, 0.3, 1.0], atol=1e-6
    )
    doubled = {"theta": 0.0, "scale": 1.5}
    np.testing.assert_allclose(
        variation.apply(doubled, np.array([0.8, -0.2, -0.4, -1.0])), [1.0, -0.3, -0.4, -1.0], atol=1e-6
    )
    assert variation.size(quarter) == pytest.approx(math.sqrt(2))
    assert variation.size({"theta": math.pi, "scale": 1.0}) == pytest.approx(2.0)
    assert variation.size(doubled) == pytest.approx(0.5)


def test_apply_undoes_compensate_for_reachable_actions(task, rng):
    variation = task.variation
    for seed in range(1000, 1020):
        v = task.variation_of(seed)
        for _ in range(50):
            wanted = np.append(rng.uniform(-1, 1, 3), rng.choice([-1.0, 1.0])).astype(np.float32)
            command = variation.compensate(v, wanted)
            assert command.dtype == np.float32 and np.all(np.abs(command) <= 1.0)
            np.testing.assert_array_equal(command[2:], wanted[2:])
            unclipped = (
                np.abs(
                    np.array(
                        [
                            math.cos(-v["theta"]) * wanted[0] - math.sin(-v["theta"]) * wanted[1],
                            math.sin(-v["theta"]) * wanted[0] + math.cos(-v["theta"]) * wanted[1],
                        ]
                    )
                )
                / v["scale"]
            )
            if np.all(unclipped <= 1.0):  # reachable
                np.testing.assert_allclose(variation.apply(v, command), wanted, atol=1e-5)


def test_variation_in_info_not_in_observation(task):
    env = task.make_env()
    try:
        obs, info = env.reset(seed=ROTATED_SEED)
        assert info["variation"] == task.variation_of(ROTATED_SEED)
        assert isinstance(obs, np.ndarray) and obs.shape == (64, 64, 3) and obs.dtype == np.uint8
        assert env.observation_space.contains(obs)
        obs, _, _, _, info = env.step(np.zeros(3, np.float32))
        assert info["variation"] == task.variation_of(ROTATED_SEED)
        assert env.observation_space.contains(obs)
        # a reset without a seed keeps the member; a reset with another seed draws its own
        _, info = env.reset()
        assert info["variation"] == task.variation_of(ROTATED_SEED)
        _, info = env.reset(seed=ROTATED_SEED + 1)
        assert info["variation"] == task.variation_of(ROTATED_SEED + 1)
    finally:
        env.close()


def test_the_arm_moves_in_the_rotated_frame(task):
    """Commanding +x on a seed turned by about a right angle moves the gripper mostly along y."""
    theta = task.variation_of(ROTATED_SEED)["theta"]
    env = task.make_env()
    try:
        env.reset(seed=ROTATED_SEED)
        start = read_fetch_state(env).grip_pos
        for _ in range(3):
            env.step(np.array([0.5, 0.0, 0.0], np.float32))
        moved = (read_fetch_state(env).grip_pos - start)[:2]
    finally:
        env.close()
    direction = math.atan2(moved[1], moved[0])
    assert np.linalg.norm(moved) > 0.02
    assert abs(math.remainder(direction - theta, 2 * math.pi)) < 0.3


def test_expert_succeeds_on_a_rotated_seed(task):
    assert abs(task.variation_of(ROTATED_SEED)["theta"]) > 1.0
    env = task.make_env()
    try:
        trajectory = rollout(env, seed=ROTATED_SEED, policy=None)
    finally:
        env.close()
    assert trajectory.success


@pytest.mark.parametrize(
    "kwargs",
    [
        {"max_rotation": -0.1},
        {"max_rotation": 4.0},
        {"max_rotation": "half"},
        {"max_rotation": float("nan")},
        {"scale_range": (0.0, 1.0)},
        {"scale_range": (1.5, 1.0)},
        {"scale_range": (1.0,)},
        {"scale_range": (1.0, float("inf"))},
        {"scale_range": None},
        {"scale_range": ("1", "2")},
        {"scale_range": (1.0, 1.2, 1.5)},
        {"max_episode_steps": 0},
    ],
)
def test_bad_parameters_raise_user_error(kwargs):
    with pytest.raises(UserError) as excinfo:
        make_task("fetch-family", **kwargs)
    message = str(excinfo.value)
    assert "\n" not in message and "got" in message
