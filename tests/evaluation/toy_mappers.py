"""A conditioned mapper for a toy pi*, fitted on random pairs: its output is arbitrary but fixed,
so a test can recompute what a protocol must have fed it."""

from __future__ import annotations

from pathlib import Path

import torch

from metadagger.mapping.config import MapperConfig
from metadagger.mapping.mappers import Mapper
from metadagger.mapping.train import train_mapper
from metadagger.metal_dagger.store import PairSplit
from metadagger.policies import Policy


def random_conditioned_mapper(pistar: Policy, out_dir: Path) -> Mapper:
    """A ``conditioned`` mapper for ``pistar``'s head and context sizes, saved in ``out_dir``."""
    dim, width = pistar.head_vector().shape[0], 2 * pistar.net.feature_dim
    g = torch.Generator().manual_seed(0)
    w_bc, w_da, context = (
        torch.randn(8, dim, generator=g),
        torch.randn(8, dim, generator=g),
        torch.randn(8, width, generator=g),
    )
    split = PairSplit(
        w_bc_train=w_bc[:6],
        w_da_train=w_da[:6],
        w_bc_val=w_bc[6:],
        w_da_val=w_da[6:],
        train_seeds=tuple(range(6)),
        val_seeds=(6, 7),
        context_train=context[:6],
        context_val=context[6:],
    )
    return train_mapper(split, MapperConfig(kind="conditioned"), out_dir, progress=False)
