"""Batched head fits: a head does not depend on the fits beside it, and is the fit BC would make."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from metadagger.errors import DivergedError
from metadagger.imitation.bc import BCConfig, fit_bc, head_fit
from metadagger.imitation.data import Dataset
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.head_fits import HeadFit, Prior, fit_heads
from metadagger.imitation.lanes import Lanes, run_chains
from metadagger.policies import Policy, PolicyNet
from metadagger.utils.kernels import mkl_vector_math_calls

OUT, DIM = 5, 16


def _fit(n: int, seed: int, *, discrete: bool = True, epochs: int = 3, lr: float = 1e-2) -> HeadFit:
    generator = torch.Generator().manual_seed(seed)
    targets = torch.randint(0, OUT, (n,), generator=generator) if discrete else torch.randn(n, OUT, generator=generator)
    return HeadFit(
        head=torch.randn(OUT * DIM + OUT, generator=generator) * 0.1,
        features=torch.rand(n, DIM, generator=generator),
        targets=targets,
        orders=torch.stack([torch.randperm(n, generator=generator) for _ in range(epochs)]),
        lr=lr,
        weight_decay=0.0,
        batch_size=4,
        called=f"fit {seed}",
    )


@pytest.mark.parametrize("discrete", [True, False])
def test_a_head_does_not_depend_on_its_batch_mates(discrete):
    # sizes with short last batches, one row, and more steps than the others
    fits = [_fit(n, seed, discrete=discrete) for seed, n in enumerate([9, 1, 30, 4, 13])]
    alone = [fit_heads([fit], out_dim=OUT, discrete=discrete)[0] for fit in fits]
    together = fit_heads(fits, out_dim=OUT, discrete=discrete)
    backwards = fit_heads(fits[::-1], out_dim=OUT, discrete=discrete)[::-1]
    pairs = [fit_heads([fits[i], fits[(i + 2) % len(fits)]], out_dim=OUT, discrete=discrete)[0] for i in range(5)]
    for mates in (together, backwards, pairs):
        for mine, theirs in zip(alone, mates):
            assert torch.equal(mine.head, theirs.head)
            assert mine.losses == theirs.losses


def test_fits_with_other_settings_are_grouped_and_each_is_as_alone():
    fits = [_fit(10, 0, lr=1e-2), _fit(7, 1, lr=1e-3), _fit(12, 2, lr=1e-2)]
    together = fit_heads(fits, out_dim=OUT, discrete=True)
    for fit, theirs in zip(fits, together):
        assert torch.equal(fit_heads([fit], out_dim=OUT, discrete=True)[0].head, theirs.head)


@pytest.mark.parametrize("discrete", [True, False])
@pytest.mark.parametrize("weight_decay", [0.0, 1e-2])
def test_a_batched_fit_is_the_fit_bc_makes_up_to_rounding(discrete, weight_decay):
    """The same data, batch orders and Adam as fit_bc's head-only fit: equal heads and losses but
    for the last bits (the loss is summed over a padded batch)."""
    rng = np.random.default_rng(0)
    net = PolicyNet(obs_shape=(8, 8, 3), n_outputs=OUT, discrete=discrete, conv_channels=(4,), kernel_sizes=(3,))
    policy = Policy(net=net, task="test")
    n = 23
    labels = rng.integers(0, OUT, n) if discrete else rng.normal(size=(n, OUT)).astype(np.float32)
    data = Dataset(obs=rng.integers(0, 255, (n, 8, 8, 3), dtype=np.uint8), labels=labels)
    config = BCConfig(lr=1e-2, batch_size=4, epochs=5, head_only=True, seed=3, weight_decay=weight_decay)
    cache = FeatureCache(policy)
    request = head_fit(policy, data, config, cache, called="the test's fit")
    [batched] = fit_heads([request], out_dim=OUT, discrete=discrete)
    losses = fit_bc(policy, data, config, cache=cache)["loss"]
    torch.testing.assert_close(batched.head, policy.head_vector(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(batched.losses, losses, rtol=1e-5)
    assert not torch.equal(batched.head, request.head)  # it did fit


def test_a_diverging_fit_is_named():
    bad = _fit(8, 0)
    bad.features[3, 1] = float("inf")
    with pytest.raises(DivergedError, match="fit 0 diverged"):
        fit_heads([_fit(8, 1), bad], out_dim=OUT, discrete=True)


def test_fits_asked_for_in_chains_are_the_fits_alone():
    net = PolicyNet(obs_shape=(8, 8, 3), n_outputs=OUT, discrete=True, conv_channels=(4,), kernel_sizes=(3,))
    fits = [[_fit(9, 0), _fit(5, 1)], [_fit(14, 2)], [_fit(3, 3), _fit(6, 4), _fit(11, 5)]]

    def chain(mine):
        return lambda lane: [lane.fit(fit).head for fit in mine]

    with Lanes(_NoTask(), net, width=2) as lanes:
        heads = run_chains(lanes, [chain(mine) for mine in fits])
    for mine, got in zip(fits, heads):
        for fit, head in zip(mine, got):
            assert torch.equal(fit_heads([fit], out_dim=OUT, discrete=True)[0].head, head)


class _NoTask:
    """A task whose envs are never made: the chains above only fit."""

    def make_env(self):  # pragma: no cover - never called
        raise AssertionError("no episode was asked for")


def _with_prior(fit: HeadFit, mean: torch.Tensor, weight: torch.Tensor) -> HeadFit:
    return dataclasses.replace(fit, prior=Prior(mean=mean, weight=weight))


@pytest.mark.parametrize("discrete", [True, False])
def test_a_prior_pulls_toward_its_mean_as_far_as_its_weight_says(discrete):
    """No weight: the plain fit's head. A huge weight: the mean. Zero mean and the weight decay's
    strength everywhere: the weight-decay fit, up to rounding. Each coordinate is pulled alone."""
    fit = _fit(13, 0, discrete=discrete, epochs=100)  # Adam moves a weight at most lr a step
    size = fit.head.numel()
    mean = torch.linspace(-0.5, 0.5, size)
    plain = fit_heads([fit], out_dim=OUT, discrete=discrete)[0]
    unweighted = fit_heads([_with_prior(fit, mean, torch.zeros(size))], out_dim=OUT, discrete=discrete)[0]
    assert torch.equal(plain.head, unweighted.head) and plain.losses == unweighted.losses
    pinned = fit_heads([_with_prior(fit, mean, torch.full((size,), 1e6))], out_dim=OUT, discrete=discrete)[0]
    torch.testing.assert_close(pinned.head, mean, atol=1e-4, rtol=0)
    decayed = fit_heads([dataclasses.replace(fit, weight_decay=0.5)], out_dim=OUT, discrete=discrete)[0]
    as_prior = fit_heads(
        [_with_prior(fit, torch.zeros(size), torch.full((size,), 0.5))], out_dim=OUT, discrete=discrete
    )
    torch.testing.assert_close(as_prior[0].head, decayed.head, rtol=1e-5, atol=1e-6)
    half = torch.zeros(size)
    half[: size // 2] = 1e6  # only the first half pinned
    partly = fit_heads([_with_prior(fit, mean, half)], out_dim=OUT, discrete=discrete)[0].head
    torch.testing.assert_close(partly[: size // 2], mean[: size // 2], atol=1e-4, rtol=0)
    assert not torch.allclose(partly[size // 2 :], mean[size // 2 :], atol=1e-2)


def test_a_head_with_a_prior_does_not_depend_on_its_batch_mates():
    fits = [_fit(n, seed) for seed, n in enumerate([9, 30, 4])]
    size = fits[0].head.numel()
    priored = [_with_prior(fit, torch.full((size,), 0.1 * k), torch.full((size,), 0.3)) for k, fit in enumerate(fits)]
    alone = [fit_heads([fit], out_dim=OUT, discrete=True)[0].head for fit in priored]
    mixed = fit_heads([priored[0], fits[1], priored[1], fits[0], priored[2]], out_dim=OUT, discrete=True)
    for mine, theirs in zip(alone, [mixed[0], mixed[2], mixed[4]]):
        assert torch.equal(mine, theirs.head)
    assert torch.equal(mixed[1].head, fit_heads([fits[1]], out_dim=OUT, discrete=True)[0].head)


def test_a_prior_shaped_otherwise_than_the_head_is_refused_naming_the_fit():
    fit = _fit(5, 0)
    with pytest.raises(ValueError, match="fit 0: a prior's mean .* must be shaped as the head"):
        _with_prior(fit, torch.zeros(3), torch.zeros(3))


@pytest.mark.parametrize("discrete", [True, False])
@pytest.mark.parametrize("prior", [False, True])
def test_batched_fits_call_no_kernel_whose_bits_depend_on_the_cpu(discrete, prior):
    """Every kernel of a batched fit (with weight decay, with a prior, heads ending at other steps)
    is one the pins fix on every x86-64 CPU: none of MKL's vector math, whose square roots and
    exponentials differ between an Intel Xeon and an AMD EPYC (docs/determinism.md)."""
    fits = [dataclasses.replace(_fit(n, seed, discrete=discrete), weight_decay=1e-2) for seed, n in enumerate([9, 4])]
    if prior:
        size = fits[0].head.numel()
        fits = [_with_prior(fit, torch.full((size,), 0.1), torch.full((size,), 0.3)) for fit in fits]
    assert mkl_vector_math_calls(lambda: fit_heads(fits, out_dim=OUT, discrete=discrete)) == []
