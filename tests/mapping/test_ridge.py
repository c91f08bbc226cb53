"""The ridge kind: closed form, λ by cross-validation on the training pairs, exact and deterministic."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from mapping_data import synthetic_split

from metadagger.mapping.config import MapperConfig
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.ridge import fit_ridge
from metadagger.mapping.train import evaluate_mapping, train_mapper


def test_ridge_recovers_a_linear_update_with_little_regularisation(tmp_path):
    split = synthetic_split(n_train=80, n_val=20)
    ridge = train_mapper(split, MapperConfig(kind="ridge"), tmp_path, progress=False)
    scores = evaluate_mapping(ridge, split.w_bc_val, split.w_da_val, mean_da=split.w_da_train.mean(0))
    assert scores["relative_mse"] < 0.05, scores
    assert ridge.config["fit"]["relative_alpha"] < 1.0
    assert load_mapper(tmp_path / "mapper.safetensors").config["fit"] == ridge.config["fit"]


def test_an_unpredictable_update_is_shrunk_to_the_mean_update():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(60, 10, generator=g)
    y = x + 0.5 + torch.randn(60, 10, generator=g)  # the update is noise around 0.5, unrelated to x
    core = torch.nn.Linear(10, 10)
    chosen = fit_ridge(core, x, y)
    assert chosen["relative_alpha"] >= 10.0
    with torch.no_grad():
        update = core(x) - x
    assert float((update - 0.5).abs().mean()) < 0.2  # close to the mean training update, not to the noise


def test_ridge_is_fitted_on_the_training_pairs_only_and_deterministic(tmp_path):
    clean = synthetic_split()
    shifted = dataclasses.replace(clean, w_bc_val=clean.w_bc_val + 100.0, w_da_val=clean.w_da_val - 100.0)
    a = train_mapper(clean, MapperConfig(kind="ridge"), tmp_path / "a", progress=False)
    b = train_mapper(shifted, MapperConfig(kind="ridge"), tmp_path / "b", progress=False)
    np.testing.assert_array_equal(a.map_batch(clean.w_bc_val), b.map_batch(clean.w_bc_val))
    train_mapper(clean, MapperConfig(kind="ridge"), tmp_path / "c", progress=False)
    assert (tmp_path / "a" / "mapper.safetensors").read_bytes() == (tmp_path / "c" / "mapper.safetensors").read_bytes()
