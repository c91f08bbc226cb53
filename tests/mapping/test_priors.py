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
    PRIOR_MEANS,
    STRENGTHS,
    VARIANCE_FLOOR,
    build_prior,
    choose_strength,
    residual_precision,
)
from metadagger.metal.method import SeedLearner, bc_head, demonstration, seeded
from metadagger.metal.store import PairSplit
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


def test_each_mean_is_the_training_pairs_and_its_precision_their_spread_around_it():
    split = synthetic_split()
    pistar = torch.full((split.w_da_train.shape[1],), 0.3)
    mapper = Mapper.control("mean-da", w_da_train=split.w_da_train)  # a mapper of a constant map
    priors = {mean: build_prior(mean, split, mapper=mapper, pistar_head=pistar) for mean in PRIOR_MEANS}
    mean_da = split.w_da_train.mean(dim=0)
    torch.testing.assert_close(priors["mean-da"].constant, mean_da)
    torch.testing.assert_close(priors["pistar-head"].constant, pistar)
    assert torch.equal(priors["zero"].constant, torch.zeros_like(pistar)) and priors["mapper"].constant is None
    for mean, centre in (("mean-da", mean_da), ("pistar-head", pistar), ("zero", torch.zeros_like(pistar))):
        torch.testing.assert_close(priors[mean].precision, residual_precision(split.w_da_train - centre))
    # the mapper's prior reads the mapper, per seed and for its residuals
    torch.testing.assert_close(priors["mapper"].precision, priors["mean-da"].precision)
    torch.testing.assert_close(priors["mapper"].mean_for(split.w_bc_val[0], None, mapper), mean_da)
    assert all(prior.strength == 0.0 for prior in priors.values())
    with pytest.raises(UserError, match="unknown prior mean 'median'; expected one of mapper, pistar-head"):
        build_prior("median", split, mapper=None, pistar_head=pistar)
    with pytest.raises(UserError, match="the mapper prior needs a mapper"):
        build_prior("mapper", split, mapper=None, pistar_head=pistar)


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
    task, groundtruth = CorridorTask(), str(toy_run.groundtruth)
    size = load_policy(groundtruth).head_vector().numel()
    at_mean = _split(torch.zeros(len(VAL_SEEDS), size), size)
    prior = build_prior("zero", at_mean, mapper=None, pistar_head=torch.zeros(size))
    strong, choice = choose_strength(prior, task, groundtruth, at_mean, FIT)
    assert strong.strength == max(STRENGTHS) == choice.strength and strong.precision is prior.precision
    assert list(choice.distances) == list(STRENGTHS)
    assert choice.distances[max(STRENGTHS)] < choice.distances[0.0]
    own = []
    for seed in VAL_SEEDS:
        with SeedLearner(task, groundtruth, seed, head_init_seed=FIT.head_init_seed(seed)) as learner:
            own.append(torch.from_numpy(bc_head(learner, demonstration(learner).to_dataset(), seeded(FIT, seed))))
    weak, choice = choose_strength(
        prior, task, groundtruth, dataclasses.replace(at_mean, w_da_val=torch.stack(own)), FIT
    )
    assert weak.strength <= 1e-4 and choice.distances[weak.strength] < choice.distances[max(STRENGTHS)]
    seen = []
    original = SeedLearner.__init__

    def recording(self, task, groundtruth, seed, **kwargs):
        seen.append(seed)
        original(self, task, groundtruth, seed, **kwargs)

    monkeypatch.setattr(SeedLearner, "__init__", recording)
    choose_strength(prior, task, groundtruth, at_mean, FIT, strengths=(0.0, 1.0))
    assert seen == list(VAL_SEEDS)
