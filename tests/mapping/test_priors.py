"""A prior for the head: its means, its precision from the training pairs, its strength from the validation pairs."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from mapping_data import synthetic_split
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig
from metadagger.mapping.mappers import Mapper
from metadagger.mapping.priors import (
    LIMIT,
    STRENGTHS,
    VARIANCE_FLOOR,
    ZERO,
    build_prior,
    choose_strengths,
    mean_head,
    residual_precision,
)
from metadagger.metal_dagger.method import SeedLearner, bc_head, demonstration, seeded
from metadagger.metal_dagger.store import PairSplit
from metadagger.policies import load_policy

FIT = BCConfig(lr=1e-2, batch_size=10, epochs=3, head_only=True)
VAL_SEEDS = (300, 301, 302)


def test_the_precision_is_the_inverse_mean_square_of_the_residuals_floored():
    residuals = torch.tensor([[1.0, 0.0, 0.1], [-1.0, 0.0, -0.1], [1.0, 0.0, 0.1]])
    variance = torch.tensor([1.0, 0.0, 0.01])
    floor = VARIANCE_FLOOR * float(variance.mean())
    expected = 1.0 / torch.clamp(variance, min=floor)
    torch.testing.assert_close(residual_precision(residuals), expected)
    with pytest.raises(UserError, match="at least 2 training pairs"):
        residual_precision(residuals[:1])
    with pytest.raises(UserError, match="do not vary around the prior's mean"):
        residual_precision(torch.zeros(4, 3))


def test_each_mean_is_a_mappers_map_and_its_precision_the_pairs_spread_around_it(tmp_path):
    split = synthetic_split()
    pistar = torch.full((split.w_da_train.shape[1],), 0.3)
    mappers = {
        "pistar-head": Mapper.pistar_head(pistar),
        "mean-da": Mapper.control("mean-da", w_da_train=split.w_da_train),
        ZERO: None,
    }
    centres = {"pistar-head": pistar, "mean-da": split.w_da_train.mean(dim=0), ZERO: torch.zeros_like(pistar)}
    for kind, mapper in mappers.items():
        prior = build_prior(split, mapper)
        assert prior.mean == kind and prior.strength == 0.0
        torch.testing.assert_close(mean_head(mapper, split.w_bc_val[0]), centres[kind])
        torch.testing.assert_close(prior.precision, residual_precision(split.w_da_train - centres[kind]))
    # a learned kind's mean is its map of each seed's w_BC; its precision, the residuals of its predictions
    from mapping_data import tiny_config

    from metadagger.mapping.train import train_mapper

    ridge = train_mapper(split, tiny_config("ridge"), tmp_path / "ridge", progress=False)
    prior = build_prior(split, ridge)
    predicted = ridge.map_tensor(split.w_bc_train, split.context_train)
    torch.testing.assert_close(prior.precision, residual_precision(split.w_da_train - predicted))
    context = split.context_val[1]
    torch.testing.assert_close(
        mean_head(ridge, split.w_bc_val[1], context), ridge.map_tensor(split.w_bc_val[1:2], context[None])[0]
    )
    weight = prior.prior(mean_head(ridge, split.w_bc_val[1], context)).weight
    assert torch.equal(weight, torch.zeros_like(weight))  # strength 0 until chosen


def _split(val_targets: torch.Tensor, size: int) -> PairSplit:
    """Training pairs spread 0.1 around zero on every coordinate; validation pairs with ``val_targets`` as w_DA."""
    generator = torch.Generator().manual_seed(0)
    w_da_train = torch.randn(40, size, generator=generator) * 0.1
    return PairSplit(
        w_bc_train=w_da_train.clone(),
        w_da_train=w_da_train,
        w_bc_val=val_targets.clone(),
        w_da_val=val_targets,
        train_seeds=tuple(range(40)),
        val_seeds=VAL_SEEDS,
    )


def test_the_strength_is_chosen_on_the_validation_pairs_alone(toy_run, monkeypatch):
    """Validation pairs whose w_DA is the prior's mean choose the strongest prior; pairs whose w_DA
    is the seed's own fit without a prior choose a weak one; no other seed is read."""
    task, pistar = CorridorTask(), str(toy_run.pistar)
    size = load_policy(pistar).head_vector().numel()
    at_mean = _split(torch.zeros(len(VAL_SEEDS), size), size)
    prior = build_prior(at_mean, None)
    [(strong, choice)] = choose_strengths({ZERO: (prior, None)}, task, pistar, at_mean, FIT).values()
    # w_DA is the mean itself: the grid's limit, the mean head with no fit, is kept, at distance 0
    assert strong.limit and choice.strength == LIMIT and strong.precision is prior.precision
    assert list(choice.distances) == [*STRENGTHS, LIMIT] and choice.distances[LIMIT] == 0.0
    assert choice.distances[max(STRENGTHS)] < choice.distances[0.0] and not choice.edge
    own = []
    for seed in VAL_SEEDS:
        with SeedLearner(task, pistar, seed, head_init_seed=FIT.head_init_seed(seed)) as learner:
            own.append(torch.from_numpy(bc_head(learner, demonstration(learner).to_dataset(), seeded(FIT, seed))))
    at_own = dataclasses.replace(at_mean, w_da_val=torch.stack(own))
    [(weak, choice)] = choose_strengths({ZERO: (prior, None)}, task, pistar, at_own, FIT).values()
    assert weak.strength <= 1e-4 and not weak.limit
    assert choice.distances[weak.strength] < min(choice.distances[max(STRENGTHS)], choice.distances[LIMIT])
    seen = []
    original = SeedLearner.__init__

    def recording(self, task, pistar, seed, **kwargs):
        seen.append(seed)
        original(self, task, pistar, seed, **kwargs)

    monkeypatch.setattr(SeedLearner, "__init__", recording)
    two = {ZERO: (prior, None), "pistar-head": (prior, Mapper.pistar_head(torch.zeros(size)))}
    both = choose_strengths(two, task, pistar, at_mean, FIT, strengths=(0.0, 1.0))
    assert seen == list(VAL_SEEDS)  # one demonstration a seed, whatever the number of priors
    assert both[ZERO][1] == both["pistar-head"][1]  # the same mean (zero): the same distances


def test_a_choice_is_read_back_while_its_inputs_hold_and_made_again_when_one_changes(toy_run, tmp_path, monkeypatch):
    """``chosen_priors`` writes its choice with a stamp; the same inputs, split and fit read it back,
    and another input, split or a new mean chooses again."""
    from metadagger.mapping import priors as priors_module

    task, pistar = CorridorTask(), str(toy_run.pistar)
    size = load_policy(pistar).head_vector().numel()
    split = _split(torch.zeros(len(VAL_SEEDS), size), size)
    record = tmp_path / "priors.json"
    calls = []
    original = priors_module.choose_strengths

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(priors_module, "choose_strengths", counting)

    def chosen(split: PairSplit, inputs: dict, means: dict | None = None) -> dict:
        means = {ZERO: None} if means is None else means
        return priors_module.chosen_priors(means, task, pistar, split, FIT, record=record, inputs=inputs)

    first = chosen(split, {"pistar": "a"})
    again = chosen(split, {"pistar": "a"})
    assert len(calls) == 1 and again[ZERO].limit and first[ZERO].limit  # w_DA at the mean: the limit
    assert torch.equal(again[ZERO].precision, first[ZERO].precision)
    chosen(split, {"pistar": "b"})
    other = dataclasses.replace(split, w_da_val=split.w_da_val + 1.0)
    chosen(other, {"pistar": "b"})
    chosen(other, {"pistar": "b"}, {ZERO: None, "pistar-head": Mapper.pistar_head(torch.zeros(size))})
    assert len(calls) == 4


def test_the_grid_grows_past_its_largest_finite_strength_while_that_one_is_kept(toy_run):
    """Validation w_DA set at the fit's own head under the largest finite strength: that strength
    is kept, so the grid grows tenfold past it and the choice is made again, one rule for every
    mean; and a prior at its limit is the mean head itself, with no step taken."""
    import metadagger.mapping.priors as priors_module
    from metadagger.imitation.head_fits import fit_heads

    task, pistar = CorridorTask(), str(toy_run.pistar)
    size = load_policy(pistar).head_vector().numel()
    probe = _split(torch.zeros(len(VAL_SEEDS), size), size)
    prior = build_prior(probe, None)
    [(_, first)] = choose_strengths({ZERO: (prior, None)}, task, pistar, probe, FIT, strengths=(0.0, 1e-3)).values()
    # targets: each seed's own fit at the grid's top finite strength (1e-3), which is then nearest
    targets = []
    for seed in VAL_SEEDS:
        with SeedLearner(task, pistar, seed, head_init_seed=FIT.head_init_seed(seed)) as learner:
            request = dataclasses.replace(
                priors_module.head_fit(
                    learner.policy, demonstration(learner).to_dataset(), seeded(FIT, seed), learner.cache, called="t"
                ),
                prior=dataclasses.replace(prior, strength=1e-3).prior(torch.zeros(size)),
            )
            [fitted] = fit_heads([request], out_dim=int(learner.policy.net.head.out_features), discrete=True)
            targets.append(fitted.head)
    at_top = dataclasses.replace(probe, w_da_val=torch.stack(targets))
    [(kept, choice)] = choose_strengths(
        {ZERO: (prior, None)}, task, pistar, at_top, FIT, strengths=(0.0, 1e-3)
    ).values()
    assert 1e-2 in choice.distances  # grown past 1e-3, which was the best of the first grid
    assert choice.distances[1e-3] == 0.0 and kept.strength == 1e-3 and not choice.edge
    assert list(first.distances) == [0.0, 1e-3, LIMIT]
    pinned = dataclasses.replace(request, prior=dataclasses.replace(prior, limit=True).prior(torch.ones(size)))
    [limit] = fit_heads([pinned], out_dim=int(learner.policy.net.head.out_features), discrete=True)
    assert torch.equal(limit.head, torch.ones(size)) and limit.losses == []
