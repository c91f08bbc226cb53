"""The CarRacing PID expert: config validation, per-track cache, statelessness, recovery."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from metadagger.tasks.carracing.env import CarRacingFast
from metadagger.tasks.carracing.expert import TRACK_HALF_WIDTH, PIDExpert, PIDExpertConfig, track_geometry


@pytest.fixture
def env():
    env = CarRacingFast()
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize(
    ("field", "value"),
    [("lateral_accel", 0.0), ("max_brake", 0.95), ("curvature_window", 0), ("lookahead_per_speed", -1.0)],
)
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        PIDExpertConfig(**{field: value})


def test_action_is_a_valid_upstream_action(env):
    action = PIDExpert()(env)
    assert action.dtype == np.float32 and action.shape == (3,)
    assert env.action_space.contains(action)


def test_expert_is_stateless(env):
    expert = PIDExpert()
    for _ in range(30):
        env.step(expert(env))
    position = tuple(env.car.hull.position)
    first = expert(env)
    # Asking again (or asking a fresh expert) neither changes the answer nor moves the car.
    np.testing.assert_array_equal(first, expert(env))
    np.testing.assert_array_equal(first, PIDExpert()(env))
    assert tuple(env.car.hull.position) == position


def test_geometry_is_cached_per_track(env):
    expert = PIDExpert()
    geo = expert.geometry(env)
    assert expert.geometry(env) is geo
    env.reset(seed=1)
    assert expert.geometry(env) is not geo
    assert len(expert.geometry(env).points) == len(env.track)


def test_speed_profile_allows_braking_in_time(env):
    cfg = PIDExpertConfig()
    geo = track_geometry(env.track, cfg)
    nxt = np.roll(geo.speed_limit, -1)
    step = np.linalg.norm(np.roll(geo.points, -1, axis=0) - geo.points, axis=1)
    assert np.all(geo.speed_limit**2 <= nxt**2 + 2 * cfg.brake_decel * step + 1e-6)
    assert geo.speed_limit.max() <= cfg.max_speed
    assert geo.length == pytest.approx(step.sum())


def test_expert_reads_upstream_carracing():
    upstream = gym.make("CarRacing-v3")
    try:
        upstream.reset(seed=0)
        action = PIDExpert()(upstream)
        assert upstream.action_space.contains(action)
        assert action[1] > 0  # at rest on the track it accelerates
    finally:
        upstream.close()


def test_not_reset_env_raises():
    with pytest.raises(RuntimeError, match="reset"):
        PIDExpert()(CarRacingFast())


@pytest.mark.parametrize("seed", range(4))
def test_recovers_after_random_driving(seed):
    """Random steering and gas for 60 steps puts the car on the grass; the expert brings it back."""
    env = CarRacingFast()
    env.reset(seed=seed)
    expert = PIDExpert()
    geo = expert.geometry(env)
    rng = np.random.default_rng(seed)
    for _ in range(80):  # drive onto the track's first straight
        env.step(expert(env))
    for t in range(60):
        if t % 20 == 0:
            held = np.array([rng.choice([-1.0, 1.0]), rng.uniform(0.5, 1.0), 0.0], dtype=np.float32)
        env.step(held)

    def distance() -> float:
        return float(np.min(np.linalg.norm(geo.points - np.array(env.car.hull.position), axis=1)))

    assert distance() > TRACK_HALF_WIDTH, "the perturbation should have left the tarmac"
    for _ in range(250):
        env.step(expert(env))
    assert distance() < TRACK_HALF_WIDTH
    velocity = np.array(env.car.hull.linearVelocity)
    i = int(np.argmin(np.linalg.norm(geo.points - np.array(env.car.hull.position), axis=1)))
    # back on the tarmac and driving along the track, not across or against it
    assert velocity @ geo.tangents[i] > math.cos(math.radians(45)) * np.hypot(*velocity)
    env.close()
