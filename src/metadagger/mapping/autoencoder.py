"""An autoencoder of flat weight vectors, the sigma of the paper's SAM and TAM (section 3.3.2).

Encoder and decoder are :func:`~metadagger.mapping.blocks.mlp` s, the decoder mirroring the
encoder's hidden widths. The latent code is linear (no activation), so a latent regression h can
target it with a plain MSE.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from metadagger.mapping.blocks import mlp

__all__ = ["Autoencoder"]


class Autoencoder(nn.Module):
    """sigma(w) = D(E(w)) for weight vectors of length ``dim``.

    Args:
        dim: length of the weight vectors.
        hidden: encoder hidden widths (the decoder uses them reversed).
        latent: width of the latent code.
        batchnorm: BatchNorm in every hidden block.
        dropout: Dropout probability in every hidden block.
        generator: draws the initial weights (encoder first, then decoder).
    """

    def __init__(
        self,
        *,
        dim: int,
        hidden: Sequence[int],
        latent: int,
        batchnorm: bool,
        dropout: float,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.dim = dim
        self.latent = latent
        self.encoder = mlp(dim, hidden, latent, batchnorm=batchnorm, dropout=dropout, generator=generator)
        self.decoder = mlp(
            latent, tuple(reversed(hidden)), dim, batchnorm=batchnorm, dropout=dropout, generator=generator
        )

    def encode(self, w: torch.Tensor) -> torch.Tensor:
        """Latent codes ``[N, latent]`` of weight vectors ``[N, dim]``."""
        return self.encoder(w)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Weight vectors ``[N, dim]`` of latent codes ``[N, latent]``."""
        return self.decoder(z)

    def forward(self, w: torch.Tensor) -> torch.Tensor:
        """The reconstruction D(E(w))."""
        return self.decode(self.encode(w))
