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


def _array_form(expert: PIDExpert, env: gym.Env) -> np.ndarray:
    """The expert written with numpy two-vectors, as it first was: the reference of the fast form."""
    cfg, geo, car = expert.config, expert.geometry(env), env.unwrapped.car
    angle = car.hull.angle + 0.5 * math.pi
    fwd = np.array([math.cos(angle), math.sin(angle)])
    left = np.array([-fwd[1], fwd[0]])
    vel = np.array(car.hull.linearVelocity)
    speed = float(np.hypot(*vel))
    rear = np.array(car.hull.position) - 82 * 0.02 * fwd
    offsets = rear - geo.points
    i = int(np.argmin(np.einsum("ij,ij->i", offsets, offsets)))
    along = float(offsets[i] @ geo.tangents[i])
    lateral = abs(float(offsets[i] @ np.array([-geo.tangents[i, 1], geo.tangents[i, 0]])))
    lookahead = cfg.lookahead_base + cfg.lookahead_per_speed * speed
    s = (geo.arc[i] + along + lookahead) % geo.length
    j = int(np.searchsorted(geo.arc, s, side="right")) - 1
    seg = geo.points[(j + 1) % len(geo.points)] - geo.points[j]
    d = geo.points[j] + seg * ((s - geo.arc[j]) / float(np.hypot(*seg))) - rear
    alpha = math.atan2(float(d @ left), float(d @ fwd))
    wheel = math.atan((80 + 82) * 0.02 * 2.0 * math.sin(alpha) / min(float(np.hypot(*d)), lookahead))
    if abs(alpha) > 0.5 * math.pi:
        wheel = math.copysign(0.4, alpha)
    v_target = float(geo.speed_limit[(i + np.arange(4)) % len(geo.points)].min())
    if lateral > TRACK_HALF_WIDTH:
        v_target = min(v_target, cfg.offtrack_speed)
    excess = max(abs(alpha) - cfg.free_turn, 0.0)
    v_target = min(v_target, max(v_target * math.cos(min(excess, 0.5 * math.pi)), cfg.turn_speed))
    gas = float(np.clip(cfg.gas_gain * (v_target - speed), 0.0, 1.0))
    brake = float(np.clip(cfg.brake_gain * (speed - v_target), 0.0, cfg.max_brake))
    if max(w.omega * 27 * 0.02 for w in car.wheels[2:4]) - float(vel @ fwd) > cfg.max_wheel_slip:
        gas = 0.0
    return np.array([float(np.clip(-wheel, -1.0, 1.0)), gas, brake], dtype=np.float32)


@pytest.mark.parametrize("seed", range(2))
def test_labels_are_bit_equal_to_the_array_form(seed):
    """On the track, off it, spinning and facing backwards: every label equals the array form's, bit for bit."""
    env = CarRacingFast()
    env.reset(seed=seed)
    expert = PIDExpert()
    rng = np.random.default_rng(seed)
    for t in range(600):
        action = expert(env)
        np.testing.assert_array_equal(action, _array_form(expert, env), err_msg=f"step {t}")
        if t % 100 >= 70:  # 30 steps of every 100 at random: grass, spins, wrong ways
            action = np.array([rng.uniform(-1, 1), rng.uniform(0, 1), rng.uniform(0, 0.3)], dtype=np.float32)
        env.step(action)
    env.close()
