"""Behavioural cloning and the feature cache on the toy corridor task."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.nn.utils import parameters_to_vector
from toy_task import TOY_ARCH

from metadagger.errors import DivergedError, UserError
from metadagger.imitation.bc import BCConfig, fit_bc, random_shift
from metadagger.imitation.data import Aggregate, Dataset
from metadagger.imitation.features import FeatureCache
from metadagger.policies import make_policy
from metadagger.runfolder.stamps import stamp_of
from metadagger.utils.optim import adam

FAST = BCConfig(lr=3e-3, epochs=20, batch_size=16)


def trunk_vector(policy) -> torch.Tensor:
    return parameters_to_vector(policy.net.trunk.parameters()).detach().clone()


def test_bc_reduces_loss_and_fits_the_demo(policy, demo):
    result = fit_bc(policy, demo, FAST)
    assert len(result["loss"]) == FAST.epochs and result["samples"] == len(demo)
    assert result["loss"][-1] < 0.2 * result["loss"][0]
    if policy.discrete:
        assert np.mean(policy.act_batch(demo.obs) == demo.labels) >= 0.9


def test_bc_is_deterministic(task, demo):
    heads, losses = [], []
    for _ in range(2):
        policy = make_policy(task, seed=4, **TOY_ARCH)
        losses.append(fit_bc(policy, demo, BCConfig(lr=3e-3, epochs=5, seed=11))["loss"])
        heads.append(policy.head_vector())
    assert losses[0] == losses[1]
    assert torch.equal(heads[0], heads[1])


def test_head_only_fit_leaves_the_trunk_unchanged(policy, demo):
    trunk, head = trunk_vector(policy), policy.head_vector()
    result = fit_bc(policy, demo, BCConfig(lr=3e-3, epochs=10, head_only=True))
    assert torch.equal(trunk_vector(policy), trunk)
    assert not torch.equal(policy.head_vector(), head)
    assert result["loss"][-1] < result["loss"][0]


def test_frozen_trunk_full_fit_trains_only_the_head(policy, demo):
    policy.freeze_trunk()
    trunk = trunk_vector(policy)
    fit_bc(policy, demo, BCConfig(lr=3e-3, epochs=2))
    assert torch.equal(trunk_vector(policy), trunk)


def test_feature_cache_computes_each_image_once(policy, demo):
    cache = FeatureCache(policy, batch_size=7)
    first = cache.features(demo.obs)
    with torch.no_grad():
        expected = policy.net.features(torch.from_numpy(demo.obs))
    torch.testing.assert_close(first, expected)
    distinct = len({image.tobytes() for image in demo.obs})
    assert cache.computed == len(cache) == distinct

    doubled = demo.concat(demo)
    fit_bc(policy, doubled, BCConfig(epochs=1, head_only=True), cache=cache)
    assert cache.computed == distinct  # nothing recomputed for images seen before

    with torch.no_grad():
        policy.net.trunk[0].weight.mul_(2.0)  # a new trunk invalidates every cached feature
    cache.features(demo.obs[:3])
    assert len(cache) == len({image.tobytes() for image in demo.obs[:3]})


def test_features_of_an_aggregate_equal_those_of_its_concatenation(policy, demo):
    """Part by part, each part hashed once, the same bits as the same calls on copied images."""
    parts = [Dataset(obs=demo.obs[s : s + 9], labels=demo.labels[s : s + 9]) for s in range(0, len(demo), 9)]
    aggregate = Aggregate(parts[:2])
    grown = aggregate.append(*parts[2:], demo)
    copied = FeatureCache(policy, batch_size=7)
    expected = [copied.features(aggregate.obs), copied.features(grown.obs)]
    cache = FeatureCache(policy, batch_size=7)
    assert torch.equal(cache.features_of(aggregate), expected[0])
    assert torch.equal(cache.features_of(grown), expected[1])
    assert cache.computed == copied.computed == len({image.tobytes() for image in demo.obs})


def test_features_of_read_only_images_are_computed_from_a_copy(policy, demo):
    obs = demo.obs.copy()
    obs.flags.writeable = False  # as images loaded from a file may be
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # torch warns when it wraps a read-only array
        features = FeatureCache(policy).features(obs)
    assert torch.equal(features, FeatureCache(policy).features(demo.obs))


def test_fit_on_an_aggregate_equals_the_fit_on_its_concatenation(task, demo):
    halves = Aggregate(
        [Dataset(obs=demo.obs[:12], labels=demo.labels[:12]), Dataset(obs=demo.obs[12:], labels=demo.labels[12:])]
    )
    heads = []
    for data in (demo, halves):
        policy = make_policy(task, seed=4, **TOY_ARCH)
        fit_bc(policy, data, BCConfig(lr=3e-3, epochs=3, head_only=True, seed=2), cache=FeatureCache(policy))
        heads.append(policy.head_vector())
    assert torch.equal(heads[0], heads[1])


@pytest.mark.parametrize("extra", [{}, {"augment_shift": 2}, {"batch_shards": 2}], ids=["plain", "shifted", "sharded"])
def test_a_whole_policy_fit_on_an_aggregate_equals_the_fit_on_its_concatenation(task, demo, extra):
    parts = [Dataset(obs=demo.obs[a:b], labels=demo.labels[a:b]) for a, b in ((0, 5), (5, 6), (6, len(demo)))]
    weights = []
    for data in (demo, Aggregate(parts)):  # the aggregate's images are gathered batch by batch, never concatenated
        policy = make_policy(task, seed=4, **TOY_ARCH)
        fit_bc(policy, data, BCConfig(lr=3e-3, epochs=2, batch_size=4, seed=2, **extra))
        weights.append(parameters_to_vector(policy.net.parameters()))
    assert torch.equal(weights[0], weights[1])


def test_a_cache_serves_every_policy_on_its_trunk_and_reads_features_computed_to_act(policy, demo):
    twin = policy.with_own_head()
    assert twin.net.trunk is policy.net.trunk and twin.net.head is not policy.net.head
    cache = FeatureCache(policy)
    before = policy.head_vector()
    fit_bc(twin, demo, BCConfig(head_only=True, epochs=1), cache=cache)  # the twin's head trains, not the policy's
    assert torch.equal(policy.head_vector(), before) and not torch.equal(twin.head_vector(), before)
    given = np.random.default_rng(0).normal(size=(len(demo.obs), policy.net.feature_dim)).astype(np.float32)
    carried = Dataset(obs=demo.obs, labels=demo.labels, features=given)
    reader = FeatureCache(policy)
    mixed = Aggregate([carried, Dataset(obs=demo.obs[:3], labels=demo.labels[:3])])
    features = reader.features_of(mixed)
    np.testing.assert_array_equal(features[: len(demo)].numpy(), given)  # read as carried
    assert torch.equal(features[len(demo) :], reader.features(demo.obs[:3]))
    assert reader.computed == 3  # only the part without features went through the trunk
    features[0] = 0.0
    np.testing.assert_array_equal(carried.features[0], given[0])  # the caller's copy, not the dataset's
    with pytest.raises(ValueError, match="features must be float32"):
        Dataset(obs=demo.obs, labels=demo.labels, features=given[:3])


def test_fit_rejects_mismatched_data_and_cache(policy, demo):
    with pytest.raises(UserError, match="empty dataset"):
        fit_bc(policy, Dataset.empty(demo), FAST)
    wrong = Dataset(obs=np.zeros((2, 8, 8, 3), np.uint8), labels=demo.labels[:2])
    with pytest.raises(UserError, match=r"policy expects \(16, 16, 3\)"):
        fit_bc(policy, wrong, FAST)
    with pytest.raises(UserError, match="only applies to head-only"):
        fit_bc(policy, demo, FAST, cache=FeatureCache(policy))
    with pytest.raises(UserError, match="another trunk"):
        fit_bc(policy, demo, BCConfig(head_only=True), cache=FeatureCache(policy.copy()))


def test_fit_rejects_labels_of_the_other_kind(policy, demo):
    other = np.zeros((len(demo), 3), np.float32) if policy.discrete else np.zeros(len(demo), np.int64)
    with pytest.raises(UserError, match="dataset labels"):
        fit_bc(policy, Dataset(obs=demo.obs, labels=other), FAST)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"lr": 0.0}, "lr must be > 0"),
        ({"batch_size": 0}, "batch_size must be an integer >= 1"),
        ({"epochs": 1.5}, "epochs must be an integer >= 1"),
        ({"weight_decay": -1.0}, "weight_decay must be >= 0"),
        ({"augment_shift": -1}, "augment_shift must be an integer >= 0"),
        ({"augment_shift": 1.5}, "augment_shift must be an integer >= 0"),
        ({"augment_shift": 2, "head_only": True}, "augment_shift needs a whole-policy fit"),
        ({"batch_shards": 0}, "batch_shards must be an integer >= 1"),
        ({"batch_shards": True}, "batch_shards must be an integer >= 1"),
        ({"batch_shards": 2, "head_only": True}, "batch_shards needs a whole-policy fit"),
        ({"lr_schedule": "linear"}, "lr_schedule must be one of constant, cosine"),
        ({"lr_schedule": "cosine", "head_only": True}, "lr_schedule needs a whole-policy fit"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BCConfig(**kwargs)


def test_random_shift_repeats_edge_pixels():
    images = torch.arange(2 * 6 * 5 * 3, dtype=torch.int32).reshape(2, 6, 5, 3).to(torch.uint8)
    generator = torch.Generator().manual_seed(3)
    shifted = random_shift(images, 2, generator)
    assert shifted.shape == images.shape and shifted.dtype == torch.uint8
    offsets = torch.randint(-2, 3, (2, 2), generator=torch.Generator().manual_seed(3))
    for i, (dy, dx) in enumerate(offsets.tolist()):
        rows = [min(max(r + dy, 0), 5) for r in range(6)]
        cols = [min(max(c + dx, 0), 4) for c in range(5)]
        assert torch.equal(shifted[i], images[i][rows][:, cols])
    assert random_shift(images, 0, generator) is images


def test_augmented_fit_is_deterministic_and_off_leaves_the_fit_unchanged(task, demo):
    def fit(**kwargs):
        policy = make_policy(task, seed=4, **TOY_ARCH)
        loss = fit_bc(policy, demo, BCConfig(lr=3e-3, epochs=3, seed=11, **kwargs))["loss"]
        return loss, policy.head_vector(), trunk_vector(policy)

    plain, off = fit(), fit(augment_shift=0)
    assert plain[0] == off[0] and torch.equal(plain[1], off[1]) and torch.equal(plain[2], off[2])
    first, second = fit(augment_shift=2), fit(augment_shift=2)
    assert first[0] == second[0] and torch.equal(first[1], second[1]) and torch.equal(first[2], second[2])
    assert not torch.equal(first[2], plain[2])


def test_head_init_shared_starts_every_seed_from_one_head_and_stays_out_of_default_stamps():
    seeded, shared = BCConfig(head_only=True), BCConfig(head_only=True, head_init="shared")
    assert [seeded.head_init_seed(s) for s in (3, 4)] == [3, 4]
    assert [shared.head_init_seed(s) for s in (3, 4)] == [0, 0]
    # a run made before the option existed keeps its stamps: the default is not stamped
    assert "head_init" not in stamp_of(seeded) and stamp_of(shared)["head_init"] == "shared"
    with pytest.raises(UserError, match="head_init must be one of seed, shared"):
        BCConfig(head_init="zero")


def _reference_fit(policy, demo: Dataset, config: BCConfig) -> None:
    """A whole-policy fit written out: Adam, its rate set at each epoch's start by the schedule;
    one shard steps on the batch's mean loss, K shards differentiate each shard's summed loss in
    turn, add the gradients in shard order and divide by the batch's count."""
    params = list(policy.net.parameters())
    optimizer = adam(params, lr=config.lr)
    loss_fn = torch.nn.functional.cross_entropy if policy.discrete else torch.nn.functional.mse_loss
    obs, labels = torch.from_numpy(demo.obs), torch.from_numpy(demo.labels)
    generator = torch.Generator().manual_seed(config.seed)
    for epoch in range(config.epochs):
        for group in optimizer.param_groups:
            group["lr"] = config.lr_at(epoch)
        order = torch.randperm(len(demo), generator=generator)
        for start in range(0, len(demo), config.batch_size):
            batch = order[start : start + config.batch_size]
            if config.batch_shards == 1:
                optimizer.zero_grad(set_to_none=True)
                loss_fn(policy.net(obs[batch]), labels[batch]).backward()
                optimizer.step()
                continue
            shards = [
                (x, y)
                for x, y in zip(
                    obs[batch].tensor_split(config.batch_shards), labels[batch].tensor_split(config.batch_shards)
                )
                if len(x)
            ]
            grads = [torch.autograd.grad(loss_fn(policy.net(x), y, reduction="sum"), params) for x, y in shards]
            count = len(batch) if policy.discrete else labels[batch].numel()
            for i, param in enumerate(params):
                total = grads[0][i]
                for other in grads[1:]:
                    total = total + other[i]
                param.grad = total / count
            optimizer.step()


@pytest.mark.parametrize("shards", [2, 3])
def test_sharded_fit_adds_the_shards_gradients_in_order(task, demo, shards):
    # batch 16 over the demo leaves a short last batch; 3 shards of it split unevenly
    config = BCConfig(lr=3e-3, epochs=3, batch_size=16, seed=11, batch_shards=shards)
    fitted, reference = make_policy(task, seed=4, **TOY_ARCH), make_policy(task, seed=4, **TOY_ARCH)
    fit_bc(fitted, demo, config)
    _reference_fit(reference, demo, config)
    for ours, theirs in zip(fitted.net.parameters(), reference.net.parameters()):
        assert torch.equal(ours, theirs)
    plain = make_policy(task, seed=4, **TOY_ARCH)
    fit_bc(plain, demo, BCConfig(lr=3e-3, epochs=3, batch_size=16, seed=11))
    # the same step summed another way: close to the one-shard fit, not equal to it bit for bit
    assert torch.allclose(
        parameters_to_vector(plain.net.parameters()), parameters_to_vector(fitted.net.parameters()), atol=1e-4
    )


_FIT_ON_CORES = """
import hashlib, os, sys
sys.path.insert(0, sys.argv[2])
if sys.argv[1] == "one":
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
import torch
from toy_task import TOY_ARCH, CorridorTask
from torch.nn.utils import parameters_to_vector
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.policies import make_policy
torch.set_num_threads(1)
task = CorridorTask(discrete=True)
policy = make_policy(task, seed=4, **TOY_ARCH)
demo = collect(task, [0], policy=None)[0].to_dataset()
fit_bc(policy, demo, BCConfig(lr=3e-3, epochs=3, batch_size=16, batch_shards=2))
print(hashlib.sha256(parameters_to_vector(policy.net.parameters()).detach().numpy().tobytes()).hexdigest())
"""


@pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity"), reason="needs os.sched_setaffinity to confine a process to one core"
)
def test_sharded_fit_gives_the_same_weights_on_one_core_as_on_all():
    tests = str(Path(__file__).resolve().parents[1])
    digests = [
        subprocess.run(
            [sys.executable, "-c", _FIT_ON_CORES, cores, tests], capture_output=True, text=True, check=True
        ).stdout
        for cores in ("one", "all")
    ]
    assert len(digests[0].strip()) == 64 and digests[0] == digests[1]


def test_batch_shards_stays_out_of_default_stamps():
    assert "batch_shards" not in stamp_of(BCConfig()) and stamp_of(BCConfig(batch_shards=2))["batch_shards"] == 2


def test_cosine_schedule_anneals_the_rate_epoch_by_epoch(task, demo):
    config = BCConfig(lr=3e-3, epochs=4, batch_size=16, seed=11, lr_schedule="cosine")
    assert [round(config.lr_at(e) / config.lr, 6) for e in range(4)] == [1.0, 0.853553, 0.5, 0.146447]
    assert BCConfig(lr=3e-3, epochs=4).lr_at(3) == 3e-3
    fitted, reference = make_policy(task, seed=4, **TOY_ARCH), make_policy(task, seed=4, **TOY_ARCH)
    fit_bc(fitted, demo, config)
    _reference_fit(reference, demo, config)
    assert all(torch.equal(a, b) for a, b in zip(fitted.net.parameters(), reference.net.parameters()))
    constant = make_policy(task, seed=4, **TOY_ARCH)
    fit_bc(constant, demo, BCConfig(lr=3e-3, epochs=4, batch_size=16, seed=11))
    assert not torch.equal(trunk_vector(constant), trunk_vector(fitted))
    assert "lr_schedule" not in stamp_of(BCConfig()) and stamp_of(config)["lr_schedule"] == "cosine"


@pytest.mark.parametrize("head_only", [False, True])
def test_a_diverging_fit_stops_with_one_line_naming_it_and_the_epoch(policy, demo, head_only):
    if policy.discrete and head_only:
        pytest.skip("a head's cross-entropy saturates at a huge rate (zero gradients) rather than diverging")
    config = BCConfig(lr=1e36, epochs=5, batch_size=16, head_only=head_only)
    with pytest.raises(
        DivergedError, match=r"the test fit diverged at epoch \d of 5 .*lower its learning rate \(now 1e\+36\)"
    ):
        fit_bc(policy, demo, config, called="the test fit")


@pytest.mark.parametrize("weight_decay", [0.0, 1e-3])
def test_the_head_only_fast_path_is_the_reference_epoch_to_the_bit(task, demo, monkeypatch, weight_decay):
    from metadagger.imitation import bc
    from metadagger.imitation.head_adam import LinearHeadAdam

    config = BCConfig(lr=3e-3, epochs=4, batch_size=16, seed=11, head_only=True, weight_decay=weight_decay)
    fast, reference = make_policy(task, seed=4, **TOY_ARCH), make_policy(task, seed=4, **TOY_ARCH)
    chosen = []
    real = bc._epochs

    def noting(*args, **kwargs):
        with real(*args, **kwargs) as epoch:
            chosen.append(type(epoch).__name__)
            yield epoch

    monkeypatch.setattr(bc, "_epochs", bc.contextmanager(noting))
    fast_losses = fit_bc(fast, demo, config)["loss"]
    monkeypatch.setattr(LinearHeadAdam, "supports", staticmethod(lambda head: False))
    reference_losses = fit_bc(reference, demo, config)["loss"]
    assert chosen == ["HeadAdamEpoch", "ReferenceEpoch"]
    assert fast_losses == reference_losses
    assert torch.equal(fast.head_vector(), reference.head_vector())
