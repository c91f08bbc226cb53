"""The scripted Fetch expert and the network distilled from it."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gymnasium_robotics")
pytest.importorskip("mujoco")

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402

from metadagger.errors import CheckpointError  # noqa: E402
from metadagger.tasks.fetch.env import UPSTREAM_ID, FetchState, fetch_is_success, lower_goal_to_object, read_fetch_state  # noqa: E402
from metadagger.tasks.fetch.expert import (  # noqa: E402
    CLOSE,
    OPEN,
    DistillConfig,
    DistilledFetchExpert,
    FetchExpert,
    collect_distillation_data,
    distill_fetch_expert,
    state_features,
)
from metadagger.tasks.fetch.task import expert_success  # noqa: E402
from metadagger.utils.io import save_tensors  # noqa: E402

CUBE = np.array([1.30, 0.70, 0.425])
GOAL = np.array([1.40, 0.85, 0.425])


def _state(grip, opening=0.1, cube=CUBE, goal=GOAL) -> FetchState:
    return FetchState(grip_pos=np.asarray(grip, float), object_pos=cube, goal=goal, gripper_opening=opening)


def test_config_is_validated():
    with pytest.raises(ValueError, match="gain"):
        FetchExpert(gain=0.0)
    with pytest.raises(ValueError, match="align_tol"):
        FetchExpert(align_tol=0.5)
    with pytest.raises(ValueError, match="noise"):
        DistillConfig(noise=-0.1)
    with pytest.raises(ValueError, match="seeds"):
        DistillConfig(seeds=())
    with pytest.raises(ValueError, match="grip_pos"):
        FetchState(grip_pos=np.zeros(2), object_pos=CUBE, goal=GOAL, gripper_opening=0.1)


def test_phases_of_the_controller():
    expert = FetchExpert()
    far = expert.act(_state(CUBE + [0.1, 0.1, 0.1]))
    assert far.dtype == np.float32 and far.shape == (4,) and np.all(np.abs(far) <= 1)
    assert far[3] == OPEN and far[0] < 0 and far[1] < 0  # heads for the cube, fingers open
    beside_low = expert.act(_state(CUBE + [0.06, 0.0, 0.0]))
    assert beside_low[3] == OPEN and beside_low[:2].tolist() == [0.0, 0.0] and beside_low[2] > 0  # rises first
    above = expert.act(_state(CUBE + [0.0, 0.0, 0.05]))
    assert above[3] == OPEN and above[2] < 0  # descends
    at_cube = expert.act(_state(CUBE + [0.0, 0.0, 0.005]))
    assert at_cube[3] == CLOSE
    holding = expert.act(_state(CUBE + [0.0, 0.0, 0.003], opening=0.048))
    assert holding[3] == CLOSE and holding[0] > 0 and holding[1] > 0 and holding[2] > 0  # carries, lifted
    missed = expert.act(_state(CUBE + [0.0, 0.0, 0.005], opening=0.0))
    assert missed[3] == OPEN  # fingers closed on nothing at the cube: open again
    closing = expert.act(_state(CUBE + [0.018, 0.0, 0.012], opening=0.08))
    assert closing[3] == CLOSE  # fingers on their way round the cube: finish the grasp


def test_controller_is_a_function_of_the_state():
    expert = FetchExpert()
    state = _state(CUBE + [0.03, -0.02, 0.04], opening=0.07)
    np.testing.assert_array_equal(expert.act(state), expert.act(state))


def test_expert_succeeds_on_a_few_seeds():
    assert expert_success(seeds=[3, 4]) == [True, True]


def test_regrasps_a_dropped_cube():
    expert = FetchExpert()
    fetch = gym.make(UPSTREAM_ID).unwrapped
    try:
        fetch.reset(seed=0)
        lower_goal_to_object(fetch)
        lifted = dropped = False
        for step in range(50):
            state = read_fetch_state(fetch)
            lifted = lifted or state.object_pos[2] > state.goal[2] + 0.01
            dropped = dropped or (
                lifted and state.gripper_opening > 0.09 and state.object_pos[2] < state.goal[2] + 0.002
            )
            action = expert.act(state)
            if lifted and step < 24:
                action[3] = OPEN  # drop the cube once it is in the air
            fetch.step(action)
        assert lifted and dropped
        assert fetch_is_success(fetch)
    finally:
        fetch.close()


def test_features_are_relative_and_scaled():
    features = state_features(_state(CUBE + [0.0, 0.0, 0.1], opening=0.05))
    assert features.dtype == np.float32 and features.shape == (7,)
    np.testing.assert_allclose(features, [0, 0, -1, 1, 1.5, 0, 0.5], atol=1e-5)


def test_collected_labels_come_from_the_controller():
    features, labels = collect_distillation_data(DistillConfig(seeds=(5,), noise=0.2))
    assert features.shape == (50, 7) and labels.shape == (50, 4)
    assert set(np.unique(labels[:, 3])) <= {OPEN, CLOSE}


def test_distillation_is_deterministic_and_round_trips(tmp_path):
    config = DistillConfig(seeds=(0, 1), epochs=2, hidden=16)
    a, b = distill_fetch_expert(config), distill_fetch_expert(config)
    for pa, pb in zip(a.net.parameters(), b.net.parameters()):
        torch.testing.assert_close(pa, pb)
    path = a.save(tmp_path / "expert.safetensors")
    loaded = DistilledFetchExpert.load(path)
    state = _state(CUBE + [0.02, 0.01, 0.05])
    np.testing.assert_array_equal(loaded.act(state), a.act(state))
    assert loaded.act(state)[3] in (OPEN, CLOSE)


def test_loading_a_wrong_file_is_a_checkpoint_error(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        DistilledFetchExpert.load(tmp_path / "missing.safetensors")
    other = save_tensors(tmp_path / "other.safetensors", {"x": torch.zeros(2)}, metadata={"kind": "Policy"})
    with pytest.raises(CheckpointError, match="not a distilled Fetch expert"):
        DistilledFetchExpert.load(other)


@pytest.mark.slow
def test_distilled_expert_succeeds():
    expert = distill_fetch_expert(DistillConfig())
    assert np.mean(expert_success(seeds=range(20), expert=expert)) >= 0.9


def test_the_state_read_is_upstreams_whole_observation_to_the_bit():
    """read_fetch_state reads three positions, not upstream's whole observation: the same values, on
    every step of an episode with a noisy grasp and a drop."""
    expert = FetchExpert()
    fetch = gym.make(UPSTREAM_ID).unwrapped
    rng = np.random.default_rng(0)
    try:
        fetch.reset(seed=1)
        lower_goal_to_object(fetch)
        for step in range(60):
            state = read_fetch_state(fetch)
            grip, cube, _, fingers, *_ = fetch.generate_mujoco_observations()
            np.testing.assert_array_equal(state.grip_pos, grip, err_msg=f"step {step}")
            np.testing.assert_array_equal(state.object_pos, np.ravel(cube), err_msg=f"step {step}")
            assert state.gripper_opening == float(np.sum(fingers))
            action = expert.act(state)
            action[:3] += rng.normal(0, 0.3, 3).astype(np.float32)
            if step in range(30, 36):
                action[3] = OPEN
            fetch.step(np.clip(action, -1, 1))
    finally:
        fetch.close()
