"""DAgger on the toy corridor: it fixes the drift of a policy cloned from one demonstration."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from toy_task import TOY_ARCH

from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.whole_policy_dagger import DAggerConfig, run_whole_policy_dagger
from metadagger.policies import make_policy

FIT = BCConfig(lr=3e-3, epochs=20, batch_size=16)
HELD_OUT = list(range(100, 120))


def success_rate(task, policy, seeds) -> float:
    return float(np.mean([t.success for t in collect(task, seeds, policy=policy)]))


def test_dagger_improves_over_bc_on_unseen_roads(discrete_task, discrete_demo):
    policy = make_policy(discrete_task, seed=0, **TOY_ARCH)
    fit_bc(policy, discrete_demo, FIT)
    bc_success = success_rate(discrete_task, policy, HELD_OUT)

    calls = []
    result = run_whole_policy_dagger(
        policy,
        discrete_task,
        range(6),
        initial=discrete_demo,
        config=DAggerConfig(rounds=2, bc=FIT),
        on_round=lambda i, p, m: calls.append((i, p is policy, m["dagger/dataset_size"])),
    )
    dagger_success = success_rate(discrete_task, policy, HELD_OUT)
    # measured with policy seeds 0-4: BC 0.05-0.20, DAgger 1.00 on these 20 unseen seeds
    assert bc_success <= 0.5
    assert dagger_success >= bc_success + 0.4

    rounds = result.rounds
    assert [m["dagger/round"] for m in rounds] == [1, 2]
    assert rounds[-1]["dagger/success_rate"] > rounds[0]["dagger/success_rate"]
    assert calls == [(i + 1, True, m["dagger/dataset_size"]) for i, m in enumerate(rounds)]


def test_expert_queries_are_cumulative(discrete_task, discrete_demo):
    policy = make_policy(discrete_task, seed=0, **TOY_ARCH)
    config = DAggerConfig(rounds=2, bc=BCConfig(lr=3e-3, epochs=1, head_only=True))
    result = run_whole_policy_dagger(policy, discrete_task, [0, 1], initial=discrete_demo, config=config)
    first, second = result.rounds
    assert first["dagger/expert_queries"] == first["dagger/dataset_size"] > len(discrete_demo)
    assert second["dagger/expert_queries"] == second["dagger/dataset_size"] == len(result.dataset)
    np.testing.assert_array_equal(result.dataset.obs[: len(discrete_demo)], discrete_demo.obs)
    per_round = second["dagger/dataset_size"] - first["dagger/dataset_size"]
    assert per_round == second["dagger/mean_steps"] * 2


def test_head_only_dagger_computes_each_image_once(discrete_task, discrete_demo):
    policy = make_policy(discrete_task, seed=0, **TOY_ARCH)
    policy.freeze_trunk()
    bc = BCConfig(lr=3e-3, epochs=2, head_only=True)
    cache = FeatureCache(policy)
    fit_bc(policy, discrete_demo, bc, cache=cache)
    result = run_whole_policy_dagger(
        policy, discrete_task, [0, 1, 2], initial=discrete_demo, config=DAggerConfig(rounds=3, bc=bc), cache=cache
    )
    distinct = len({image.tobytes() for image in result.dataset.obs})
    assert cache.computed == distinct < len(result.dataset)


def test_reset_each_round_refits_from_a_fresh_head(discrete_task, discrete_demo):
    bc = BCConfig(lr=3e-3, epochs=3, head_only=True, seed=3)
    policy = make_policy(discrete_task, seed=0, **TOY_ARCH)
    fit_bc(policy, discrete_demo, FIT)
    result = run_whole_policy_dagger(
        policy,
        discrete_task,
        [0, 1],
        initial=discrete_demo,
        config=DAggerConfig(rounds=1, bc=bc, reset_each_round=True),
    )
    # the same refit done by hand: the pre-DAgger weights, a head reset from bc.seed, one fit
    by_hand = make_policy(discrete_task, seed=0, **TOY_ARCH)
    fit_bc(by_hand, discrete_demo, FIT)
    by_hand.reset_head(bc.seed)
    fit_bc(by_hand, result.dataset, bc)
    torch.testing.assert_close(policy.head_vector(), by_hand.head_vector())


@pytest.mark.parametrize(
    "kwargs,match", [({"rounds": 0}, "rounds must be an integer >= 1"), ({"bc": {}}, "bc must be a BCConfig")]
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DAggerConfig(**kwargs)


def test_needs_a_seed(discrete_task, discrete_demo):
    policy = make_policy(discrete_task, seed=0, **TOY_ARCH)
    with pytest.raises(ValueError, match="at least one seed"):
        run_whole_policy_dagger(policy, discrete_task, [], initial=discrete_demo, config=DAggerConfig(rounds=1))
