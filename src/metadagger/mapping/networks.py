"""The networks of the learned mapper kinds (paper 3.3): DM's MLP, SAM's and TAM's autoencoders
and their latent map h. Each builder takes the head length, the architecture fields of
:class:`~metadagger.mapping.config.MapperConfig` and a generator, and returns the untrained
networks named as in the kind's :class:`~metadagger.mapping.registry.Route`."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from metadagger.mapping.autoencoder import Autoencoder
from metadagger.mapping.blocks import mlp


def build_dm(
    dim: int,
    *,
    hidden: Sequence[int],
    batchnorm: bool,
    dropout: float,
    generator: torch.Generator | None = None,
    **_: object,
) -> dict[str, nn.Module]:
    """DM (3.3.1): one MLP from standardised w_BC to standardised w_DA."""
    return {"dm": mlp(dim, hidden, dim, batchnorm=batchnorm, dropout=dropout, generator=generator)}


def build_sam(dim: int, **arch: object) -> dict[str, nn.Module]:
    """SAM (3.3.2): one autoencoder sigma_ALL of w_BC and w_DA, and h between its codes."""
    return _autoencoders_and_h(("sigma_all",), dim, **arch)


def build_tam(dim: int, **arch: object) -> dict[str, nn.Module]:
    """TAM (3.3.2): autoencoders sigma_BC and sigma_DA, and h from the first's codes to the second's."""
    return _autoencoders_and_h(("sigma_bc", "sigma_da"), dim, **arch)


def _autoencoders_and_h(
    names: tuple[str, ...],
    dim: int,
    *,
    hidden: Sequence[int],
    latent: int,
    ae_hidden: Sequence[int],
    batchnorm: bool,
    dropout: float,
    ae_dropout: float,
    generator: torch.Generator | None = None,
) -> dict[str, nn.Module]:
    # autoencoders before h, so one generator gives the same weights every time
    nets: dict[str, nn.Module] = {
        name: Autoencoder(
            dim=dim, hidden=ae_hidden, latent=latent, batchnorm=batchnorm, dropout=ae_dropout, generator=generator
        )
        for name in names
    }
    nets["h"] = mlp(latent, hidden, latent, batchnorm=batchnorm, dropout=dropout, generator=generator)
    return nets
