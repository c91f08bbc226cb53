"""``metadagger/CarRacing-v0`` behaves exactly like upstream's CarRacing-v3 and looks like it."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.box2d.car_racing import CarRacing
from gymnasium.utils.env_checker import check_env

from metadagger.cli.bench_env import smooth_actions
from metadagger.errors import UserError
from metadagger.tasks.carracing.env import CarRacingFast

STEPS = 120
# Bounds on the mean absolute image error against upstream (0-255 scale). Measured on these
# 120-step episodes (STEPS, smooth_actions): episode mean 0.52 / 0.58 / 0.44 / 0.47 on seeds
# 0 / 1 / 2 / 3 (higher than on full episodes, 0.38-0.45, as the zoom-in is a larger share);
# worst single frame 1.36 / 1.26 / 1.34 / 1.20 (always frame 2, mid zoom-in); the first 50
# (zoom-in) frames 0.65 / 0.61 / 0.63 / 0.62; frames on grass 0.30 / 0.56 / 0.31 / 0.29;
# domain-randomised colours, seed 2, 15 steps: 0.77. Each bound is the worst of those plus about a third.
MAX_EPISODE_MAE = 0.8
MAX_FRAME_MAE = 1.8
MAX_ZOOM_MAE = 0.9
MAX_GRASS_MAE = 0.8
MAX_RANDOMIZED_MAE = 1.0


def rollout(env, seed: int, actions: np.ndarray) -> dict:
    """Frames, rewards, terminations, per-step car pose, tiles visited and whether on grass."""
    obs, _ = env.reset(seed=seed)
    out = {"frames": [obs], "rewards": [], "terminated": [], "pose": [], "tiles": [], "grass": []}
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        car = env.car
        out["frames"].append(obs)
        out["rewards"].append(reward)
        out["terminated"].append(terminated)
        out["pose"].append((*car.hull.position, car.hull.angle, *car.hull.linearVelocity))
        out["tiles"].append(env.tile_visited_count)
        out["grass"].append(all(not w.tiles for w in car.wheels))
        if terminated or truncated:
            break
    return {k: np.array(v) for k, v in out.items()}


@pytest.fixture(scope="module", params=[0, 1])
def episode_pair(request):
    seed = request.param
    actions = smooth_actions(seed, STEPS)
    return seed, rollout(CarRacingFast(), seed, actions), rollout(CarRacing(), seed, actions)


def mae(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def test_dynamics_equal_upstream_exactly(episode_pair):
    _, ours, upstream = episode_pair
    for key in ("rewards", "terminated", "pose", "tiles"):
        np.testing.assert_array_equal(ours[key], upstream[key], err_msg=key)


def test_image_close_to_upstream_over_the_episode(episode_pair):
    seed, ours, upstream = episode_pair
    per_frame = [mae(a, b) for a, b in zip(ours["frames"], upstream["frames"])]
    assert np.mean(per_frame) <= MAX_EPISODE_MAE, f"seed {seed}: episode MAE {np.mean(per_frame):.2f}"
    assert max(per_frame) <= MAX_FRAME_MAE, f"seed {seed}: frame {int(np.argmax(per_frame))} MAE {max(per_frame):.2f}"


def test_zoom_in_frames_are_close(episode_pair):
    _, ours, upstream = episode_pair
    zoom = slice(0, 50)  # the camera zooms in during the first second (50 frames)
    assert mae(ours["frames"][zoom], upstream["frames"][zoom]) <= MAX_ZOOM_MAE


def test_frames_on_grass_are_close(episode_pair):
    _, ours, upstream = episode_pair
    on_grass = np.flatnonzero(ours["grass"])
    assert on_grass.size, "the action sequence should drive the car onto the grass"
    frames = on_grass + 1  # frames[0] is the reset observation
    assert mae(ours["frames"][frames], upstream["frames"][frames]) <= MAX_GRASS_MAE


def test_reference_renderer_is_upstreams_image():
    actions = smooth_actions(3, 10)
    ours = rollout(CarRacingFast(render="reference"), 3, actions)
    upstream = rollout(CarRacing(), 3, actions)
    np.testing.assert_array_equal(ours["frames"], upstream["frames"])


def test_bad_render_value_is_a_user_error():
    with pytest.raises(UserError, match="render='gpu'.*'fast', 'reference'"):
        CarRacingFast(render="gpu")


def test_observation_space_and_determinism():
    env = gym.make("metadagger/CarRacing-v0")
    assert env.observation_space.shape == (96, 96, 3) and env.observation_space.dtype == np.uint8
    assert env.action_space.shape == (3,)
    actions = smooth_actions(7, 20)
    first, second = (rollout(env.unwrapped, 7, actions) for _ in range(2))
    np.testing.assert_array_equal(first["frames"], second["frames"])
    assert env.observation_space.contains(first["frames"][-1])


def test_touched_tiles_recolour_in_place():
    env = CarRacingFast()
    env.reset(seed=0)
    for action in smooth_actions(0, 60):
        env.step(action)
    visited = [i for i, tile in enumerate(env.road) if tile.road_visited]
    assert visited
    tile = env.road[visited[0]]
    assert np.array_equal(tile.color, env.road_color)
    # the tile's colour is a view into the renderer's array, also held by upstream's road_poly
    assert any(np.shares_memory(tile.color, env._road_colors) and color is tile.color for _, color in env.road_poly)


def test_constructor_arguments_pickle_and_pass_through():
    env = CarRacingFast(render="reference", lap_complete_percent=0.5, continuous=False)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.render_kind == "reference" and clone.lap_complete_percent == 0.5 and not clone.continuous
    assert isinstance(clone.action_space, gym.spaces.Discrete)


def test_domain_randomized_colours_are_drawn():
    actions = smooth_actions(2, 15)
    ours = rollout(CarRacingFast(domain_randomize=True), 2, actions)
    upstream = rollout(CarRacing(domain_randomize=True), 2, actions)
    assert mae(ours["frames"], upstream["frames"]) <= MAX_RANDOMIZED_MAE


def test_env_checker_passes():
    check_env(gym.make("metadagger/CarRacing-v0").unwrapped)


def test_the_renderer_runs_opencv_serially_with_the_same_pixels_as_its_thread_pool():
    import cv2

    actions = smooth_actions(5, STEPS)
    serial = CarRacingFast()
    assert cv2.getNumThreads() == 1  # making the renderer turned OpenCV's idle, spinning pool off
    expected = rollout(serial, 5, actions)["frames"]
    threaded = CarRacingFast()
    cv2.setNumThreads(4)  # after the renderer is made: its frames go through the pool
    try:
        frames = rollout(threaded, 5, actions)["frames"]
    finally:
        cv2.setNumThreads(1)
    assert all(np.array_equal(a, b) for a, b in zip(frames, expected, strict=True))
