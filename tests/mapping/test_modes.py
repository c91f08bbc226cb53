"""The modes kind: groups of w_DA told apart from w_BC, K and λ by cross-validation on the
training pairs; one group (the mean-DA control) when the groups carry nothing."""

from __future__ import annotations

import numpy as np
import torch

from metadagger.mapping.config import MapperConfig
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.modes import GroupMeans, fit_modes
from metadagger.mapping.train import evaluate_mapping, train_mapper
from metadagger.metal_dagger.store import PairSplit


def _grouped_split(n_train: int = 60, n_val: int = 20, dim: int = 12) -> tuple[PairSplit, np.ndarray]:
    """Two groups of seeds (a mirrored and a plain one): w_DA is its group's head plus noise, and
    w_BC a noisy half-way point that still shows the group."""
    g = np.random.default_rng(0)
    n = n_train + n_val
    group = g.random(n) < 0.5
    heads = g.normal(size=(2, dim))
    w_da = heads[group.astype(int)] + 0.1 * g.normal(size=(n, dim))
    w_bc = 0.5 * w_da + 0.3 * g.normal(size=(n, dim))
    t = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    split = PairSplit(
        w_bc_train=t(w_bc[:n_train]),
        w_da_train=t(w_da[:n_train]),
        w_bc_val=t(w_bc[n_train:]),
        w_da_val=t(w_da[n_train:]),
        train_seeds=tuple(range(n_train)),
        val_seeds=tuple(range(n_train, n)),
    )
    return split, heads[group[n_train:].astype(int)]


def test_modes_finds_the_groups_and_maps_each_seed_to_its_own(tmp_path):
    split, truth = _grouped_split()
    mapper = train_mapper(split, MapperConfig(kind="modes"), tmp_path, progress=False)
    assert mapper.config["fit"]["groups"] == 2
    predicted = mapper.map_batch(split.w_bc_val)
    assert np.abs(predicted - truth).max() < 0.2  # each validation seed gets its own group's head
    scores = evaluate_mapping(mapper, split.w_bc_val, split.w_da_val, mean_da=split.w_da_train.mean(0))
    assert scores["relative_mse"] < 0.05, scores
    again = load_mapper(tmp_path / "mapper.safetensors")
    np.testing.assert_array_equal(again.map_batch(split.w_bc_val), predicted)
    train_mapper(split, MapperConfig(kind="modes"), tmp_path / "again", progress=False)
    assert (tmp_path / "mapper.safetensors").read_bytes() == (tmp_path / "again" / "mapper.safetensors").read_bytes()


def test_groups_that_w_bc_does_not_show_give_the_mean():
    g = torch.Generator().manual_seed(0)
    y = torch.randn(60, 8, generator=g)
    x = torch.randn(60, 8, generator=g)  # unrelated to y
    core = GroupMeans(8)
    chosen = fit_modes(core, x, y)
    assert chosen["groups"] == 1
    with torch.no_grad():
        torch.testing.assert_close(core(x), y.mean(dim=0).expand(60, 8).float(), atol=1e-5, rtol=0)
