"""PolicyNet / Policy: shapes, head <-> vector, save/load, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from metadagger.errors import CheckpointError, UserError
from metadagger.policies import Policy, PolicyNet, load_policy, make_policy, tensor_mismatch
from metadagger.utils.io import load_tensors, read_metadata, save_tensors

SMALL = {"conv_channels": (4, 8), "kernel_sizes": (3, 3), "hidden": (16,)}


def small_policy(*, discrete: bool = True, n_outputs: int = 5, seed: int = 0) -> Policy:
    net = PolicyNet(obs_shape=(16, 16, 3), n_outputs=n_outputs, discrete=discrete, **SMALL)
    net.init_weights(seed)
    return Policy(net=net, task="toy")


def images(rng: np.random.Generator, n: int, shape=(16, 16, 3)) -> np.ndarray:
    return rng.integers(0, 256, (n, *shape), dtype=np.uint8)


def test_default_net_for_carracing_has_about_150k_parameters(rng):
    net = PolicyNet(obs_shape=(96, 96, 3), n_outputs=20, discrete=True)
    n_params = sum(p.numel() for p in net.parameters())
    assert 120_000 <= n_params <= 180_000
    obs = torch.from_numpy(images(rng, 2, (96, 96, 3)))
    assert net.features(obs).shape == (2, net.feature_dim)
    assert net(obs).shape == (2, 20)
    assert isinstance(net.head, torch.nn.Linear) and net.head.out_features == 20


@pytest.mark.parametrize("shape,outputs", [((64, 64, 3), 3), ((24, 24, 3), 2), ((16, 16, 1), 4)])
def test_flatten_size_follows_obs_shape(rng, shape, outputs):
    net = PolicyNet(obs_shape=shape, n_outputs=outputs, discrete=False)
    assert net(torch.from_numpy(images(rng, 3, shape))).shape == (3, outputs)


def test_discrete_and_box_actions(rng):
    obs = images(rng, 4)
    discrete, box = small_policy(discrete=True), small_policy(discrete=False, n_outputs=3)
    assert isinstance(discrete(obs[0]), int) and 0 <= discrete(obs[0]) < 5
    assert discrete.act_batch(obs).dtype == np.int64
    action = box(obs[0])
    assert action.dtype == np.float32 and action.shape == (3,)
    np.testing.assert_allclose(box.act_batch(obs)[0], action, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("spatial_softmax", [False, True])
def test_acting_gives_forwards_numbers_to_the_bit(rng, spatial_softmax):
    net = PolicyNet(obs_shape=(16, 16, 3), n_outputs=5, discrete=True, spatial_softmax=spatial_softmax, **SMALL)
    net.init_weights(0)
    obs = torch.from_numpy(images(rng, 6))
    with torch.no_grad():
        assert torch.equal(net.act_outputs(obs), net(obs))
        assert torch.equal(net.act_outputs(obs[:1]), net(obs[:1]))
    policy = Policy(net=net, task="toy")
    assert [policy(o) for o in obs.numpy()] == net(obs).argmax(1).tolist()


def test_wrong_observation_is_a_user_error(rng):
    policy = small_policy()
    with pytest.raises(UserError, match=r"uint8 arrays of shape \(N, 16, 16, 3\)"):
        policy(images(rng, 1, (8, 8, 3))[0])
    with pytest.raises(UserError, match="uint8"):
        policy(np.zeros((16, 16, 3), np.float32))


def test_one_observation_runs_on_one_thread_and_keeps_the_callers_setting(rng):
    policy = small_policy()
    seen = []
    act_outputs = policy.net.act_outputs

    def recording(obs):
        seen.append(torch.get_num_threads())
        return act_outputs(obs)

    policy.net.act_outputs = recording
    caller = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        policy(images(rng, 1)[0])
        assert torch.get_num_threads() == 3
        policy.act_batch(images(rng, 4))  # a batch uses the caller's threads
    finally:
        torch.set_num_threads(caller)
    assert seen == [1, 3]


def test_head_vector_round_trip(rng):
    policy, other = small_policy(seed=0), small_policy(seed=1)
    vector = policy.head_vector()
    assert vector.dtype == torch.float32 and vector.shape == (policy.head_size,) == (5 * 16 + 5,)
    other.load_head_vector(vector)
    torch.testing.assert_close(other.head_vector(), vector)
    other.load_head_vector(vector.numpy())  # numpy accepted too
    vector.zero_()  # head_vector() is a copy, not a view into the weights
    assert policy.head_vector().abs().sum() > 0


def test_load_head_vector_rejects_wrong_length_and_dtype():
    policy = small_policy()
    with pytest.raises(UserError, match=r"length 85 = 5\*16 \+ 5, got .*\(84,\)"):
        policy.load_head_vector(torch.zeros(84))
    with pytest.raises(UserError, match="float32"):
        policy.load_head_vector(torch.zeros(85, dtype=torch.float64))
    with pytest.raises(UserError, match="1-D"):
        policy.load_head_vector(torch.zeros(5, 17))


def test_reset_head_is_deterministic_xavier_with_zero_bias():
    a, b = small_policy(seed=0), small_policy(seed=1)
    a.reset_head(7)
    b.reset_head(7)
    torch.testing.assert_close(a.head_vector(), b.head_vector())
    assert torch.count_nonzero(a.net.head.bias) == 0
    bound = (6 / (16 + 5)) ** 0.5
    assert a.net.head.weight.abs().max() <= bound


def test_freeze_trunk_and_copy():
    policy = small_policy()
    clone = policy.copy()
    policy.freeze_trunk()
    assert not any(p.requires_grad for p in policy.net.trunk.parameters())
    assert all(p.requires_grad for p in policy.net.head.parameters())
    assert all(p.requires_grad for p in clone.net.parameters())
    clone.reset_head(3)
    assert not torch.equal(clone.head_vector(), policy.head_vector())


def test_save_load_round_trip_gives_identical_outputs(tmp_path, rng):
    policy = small_policy(discrete=False, n_outputs=3)
    path = policy.save(tmp_path / "policy.safetensors")
    loaded = load_policy(path)
    obs = images(rng, 6)
    np.testing.assert_array_equal(loaded.act_batch(obs), policy.act_batch(obs))
    assert loaded.arch == policy.arch and loaded.task == "toy"
    import metadagger

    assert metadagger.load_policy(path).head_size == policy.head_size


def test_missing_or_corrupt_checkpoint_raises_checkpoint_error(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_policy(tmp_path / "nope.safetensors")
    path = small_policy().save(tmp_path / "p.safetensors")
    path.write_bytes(path.read_bytes()[:50])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_policy(path)


def test_metadata_that_does_not_rebuild_raises_checkpoint_error(tmp_path):
    policy = small_policy()
    arch = dict(policy.arch, hidden=[32])  # tensors no longer fit this architecture
    metadata = {"format": "metadagger.policy/1", "arch": json.dumps(arch), "task": "toy"}
    save_tensors(tmp_path / "bad.safetensors", policy.net.state_dict(), metadata=metadata)
    with pytest.raises(CheckpointError, match=r"trunk\.5\.weight has shape \(16, 128\), expected \(32, 128\)"):
        load_policy(tmp_path / "bad.safetensors")
    save_tensors(tmp_path / "no-arch.safetensors", policy.net.state_dict(), metadata={"format": "metadagger.policy/1"})
    with pytest.raises(CheckpointError, match="does not rebuild"):
        load_policy(tmp_path / "no-arch.safetensors")
    save_tensors(tmp_path / "other.safetensors", {"x": torch.zeros(1)})
    with pytest.raises(CheckpointError, match="not a metadagger policy"):
        load_policy(tmp_path / "other.safetensors")


def test_tensors_that_do_not_fit_the_recorded_architecture_are_named_in_one_line(tmp_path):
    path = small_policy().save(tmp_path / "p.safetensors")
    tensors = load_tensors(path)
    tensors["head.weight"] = torch.zeros(3, 3)
    del tensors["trunk.0.bias"]
    tensors["extra"] = torch.zeros(1)
    save_tensors(path, tensors, metadata=read_metadata(path))
    with pytest.raises(CheckpointError) as info:
        load_policy(path)
    message = str(info.value)
    assert "\n" not in message
    assert f"policy checkpoint {path} does not fit the architecture its metadata records (" in message
    assert (
        "missing tensor(s) trunk.0.bias; unexpected tensor(s) extra; head.weight has shape (3, 3), expected (5, 16)"
        in message
    )
    assert message.endswith(
        "restore the file, or delete it and re-run the command that wrote it "
        "(for a run's pi*: metadagger pistar --out RUN)"
    )


def test_tensor_mismatch_lists_a_few_names_and_counts_the_rest():
    expected = {f"t{i}": torch.zeros(2) for i in range(5)}
    assert tensor_mismatch(expected, expected) == ""
    assert tensor_mismatch({}, expected) == "missing tensor(s) t0, t1, t2 and 2 more"


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"conv_channels": (4, 8), "kernel_sizes": (3,)}, "one kernel per convolution"),
        ({"hidden": (0,)}, "hidden must be"),
        ({"conv_channels": (4, 8), "kernel_sizes": (3, 3), "strides": (2,)}, "one stride per convolution"),
        ({"obs_shape": (16, 16)}, r"obs_shape must be \(H, W, C\)"),
        ({"n_outputs": 0}, "n_outputs must be a positive integer"),
    ],
)
def test_bad_architecture_is_a_user_error(kwargs, match):
    args = {"obs_shape": (16, 16, 3), "n_outputs": 3, "discrete": True, **kwargs}
    with pytest.raises(UserError, match=match):
        PolicyNet(**args)


def test_make_policy_for_carracing():
    import metadagger

    try:
        task = metadagger.make_task("carracing")
    except (UserError, ImportError, AttributeError) as exc:
        pytest.skip(f"carracing task not available: {exc}")
    policy = make_policy(task, seed=0)
    assert policy.arch["obs_shape"] == [96, 96, 3] and policy.arch["n_outputs"] == 20
    assert policy.discrete and policy.task == "carracing"


def test_load_head_vector_copies_so_training_never_writes_into_the_callers_array():
    from toy_task import CorridorTask

    from metadagger.policies import make_policy

    policy = make_policy(CorridorTask(), seed=0)
    source = np.zeros(policy.head_size, dtype=np.float32)
    policy.load_head_vector(source)
    with torch.no_grad():
        policy.net.head.weight.add_(1.0)
    assert not source.any()


def test_spatial_softmax_trunk_gives_keypoints_and_round_trips(tmp_path, rng):
    net = PolicyNet(
        obs_shape=(16, 16, 3),
        n_outputs=3,
        discrete=False,
        conv_channels=(4, 6),
        kernel_sizes=(3, 3),
        strides=(2, 1),
        hidden=(8,),
        spatial_softmax=True,
    )
    maps = torch.zeros(1, 6, 8, 8)
    maps[0, :, 0, 7] = 50.0  # every channel peaks in the top-right corner
    keypoints = net.trunk[-3](maps)  # the SpatialSoftmax layer
    np.testing.assert_allclose(keypoints[0, :6].numpy(), 1.0, atol=1e-4)  # x = +1
    np.testing.assert_allclose(keypoints[0, 6:].numpy(), -1.0, atol=1e-4)  # y = -1
    assert net.trunk[-2].in_features == 12  # 2 coordinates per channel feed the hidden layer
    policy = Policy(net=net, task="toy")
    loaded = load_policy(policy.save(tmp_path / "p.safetensors"))
    obs = images(rng, 4)
    np.testing.assert_array_equal(loaded.act_batch(obs), policy.act_batch(obs))


def test_a_policy_file_with_nan_float16_or_of_the_wrong_kind_is_one_line(tmp_path):
    policy = small_policy()
    path = policy.save(tmp_path / "policy.safetensors")
    tensors, metadata = load_tensors(path), read_metadata(path)
    with pytest.raises(UserError, match="holds NaN or infinite values"):
        save_tensors(
            tmp_path / "nan.safetensors", {**tensors, "head.bias": torch.full_like(tensors["head.bias"], float("nan"))}
        )
    assert not (tmp_path / "nan.safetensors").exists()
    from safetensors.torch import save_file

    bad = {**tensors, "head.bias": torch.full_like(tensors["head.bias"], float("nan"))}
    save_file(bad, str(tmp_path / "nan.safetensors"), metadata={"metadagger": json.dumps(metadata)})
    with pytest.raises(CheckpointError, match=r"nan.safetensors holds NaN or infinite values in tensor 'head.bias'"):
        load_policy(tmp_path / "nan.safetensors")
    half = {name: t.half() if t.is_floating_point() else t for name, t in tensors.items()}
    save_file(half, str(tmp_path / "half.safetensors"), metadata={"metadagger": json.dumps(metadata)})
    with pytest.raises(CheckpointError, match="as float16, expected float32"):
        load_policy(tmp_path / "half.safetensors")
    with pytest.raises(
        CheckpointError,
        match=r"is a folder \(it holds half.safetensors, nan.safetensors, policy.safetensors\); pass the .safetensors "
        r"file itself",
    ):
        load_policy(tmp_path)
    (tmp_path / "config.yaml").write_text("task: carracing\n")
    with pytest.raises(
        CheckpointError, match="config.yaml is not a .safetensors file; pass a file that metadagger wrote"
    ):
        load_policy(tmp_path / "config.yaml")
    with pytest.raises(CheckpointError, match="expected the path of a .safetensors file, got None"):
        load_policy(None)


def test_a_batch_passed_to_policy_points_to_act_batch(rng):
    policy = small_policy()
    with pytest.raises(UserError, match=r"use policy.act_batch\(obs\) for a batch"):
        policy(images(rng, 4))
