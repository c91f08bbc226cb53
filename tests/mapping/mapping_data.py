"""Synthetic weight pairs and a tiny mapper config, so every mapping test runs in about a second."""

from __future__ import annotations

import numpy as np
import torch

from metadagger.mapping.config import MapperConfig, paper_config
from metadagger.metal_dagger.store import PairSplit

DIM = 12


def synthetic_split(
    *,
    n_train: int = 60,
    n_val: int = 20,
    dim: int = DIM,
    seed: int = 0,
    context_dim: int = 4,
    context_effect: float = 0.0,
) -> PairSplit:
    """w_BC on a rank-3 subspace; w_DA = w_BC @ M + b + noise (a linear relation a mapper can learn),
    plus ``context_effect`` times a linear map of each seed's context (``context_dim`` standard
    normal numbers, drawn apart from w_BC: only a mapper that reads them can predict that part)."""
    g = np.random.default_rng(seed)
    n = n_train + n_val
    w_bc = g.normal(size=(n, 3)) @ g.normal(size=(3, dim)) * 0.3 + 0.01 * g.normal(size=(n, dim))
    w_da = w_bc @ (0.8 * np.eye(dim) + 0.1 * g.normal(size=(dim, dim))) + 0.2 + 0.01 * g.normal(size=(n, dim))
    context = np.random.default_rng(seed + 1000).normal(size=(n, context_dim))
    w_da = w_da + context_effect * context @ np.random.default_rng(seed + 2000).normal(size=(context_dim, dim))
    w_bc, w_da, context = (torch.tensor(a, dtype=torch.float32) for a in (w_bc, w_da, context))
    return PairSplit(
        w_bc_train=w_bc[:n_train],
        w_da_train=w_da[:n_train],
        w_bc_val=w_bc[n_train:],
        w_da_val=w_da[n_train:],
        train_seeds=tuple(range(n_train)),
        val_seeds=tuple(range(n_train, n)),
        context_train=context[:n_train],
        context_val=context[n_train:],
    )


def tiny_config(kind: str, **overrides) -> MapperConfig:
    """Paper settings shrunk to small widths and few epochs, with a learning rate to match."""
    small = dict(hidden=(32,), latent=4, ae_hidden=(16,), dropout=0.1, lr=3e-3, epochs=40, ae_epochs=40)
    return paper_config(kind, **{**small, **overrides})
