"""How one mapper is built and trained: :class:`MapperConfig`, and the paper's settings per kind."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from metadagger.errors import UserError
from metadagger.mapping.registry import get_kind, kind_names


@dataclass(frozen=True)
class MapperConfig:
    """How one mapper is built and trained (defaults: the paper's SAM/TAM; see :func:`paper_config`).

    Fig. 6 draws the blocks but the paper does not print the widths: ``hidden``, ``latent`` and
    ``ae_hidden`` are our choices, sized for heads of ~200 to ~1300 weights.
    """

    kind: str = "sam"
    """A kind of :mod:`metadagger.mapping.registry` (``metadagger train-mapper --help`` lists them)."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden widths of the mapping MLP (DM's network, or h for SAM/TAM)."""
    latent: int = 64
    """Latent width of the autoencoder(s) (SAM/TAM)."""
    ae_hidden: tuple[int, ...] = (256,)
    """Encoder hidden widths of the autoencoder(s); the decoder mirrors them."""
    batchnorm: bool = True
    """BatchNorm in every hidden block of every network."""
    dropout: float = 0.1
    """Dropout in the hidden blocks of the mapping MLP (DM, or h), in [0, 1)."""
    ae_dropout: float = 0.0
    """Dropout in the hidden blocks of the autoencoder(s), in [0, 1)."""
    lr: float = 1e-4
    """Adam learning rate, every network."""
    weight_decay: float = 1e-4
    """Adam weight decay of the mapping MLP (DM, or h)."""
    ae_weight_decay: float = 1e-5
    """Adam weight decay of the autoencoder(s)."""
    batch_size: int = 10
    """Rows per gradient step."""
    epochs: int = 1000
    """Epochs of the mapping MLP; the paper uses 500 for DM, 1000 for SAM/TAM, 2000 on Fetch."""
    ae_epochs: int = 1000
    """Epochs of each autoencoder (SAM/TAM)."""
    seed: int = 0
    """Seeds the initial weights, the batch order and Dropout."""

    def __post_init__(self) -> None:
        if self.kind not in kind_names():
            raise UserError(f"MapperConfig.kind must be one of {', '.join(kind_names())}, got {self.kind!r}")
        for name in ("hidden", "ae_hidden"):
            widths = getattr(self, name)
            if not isinstance(widths, tuple) or not all(_is_int(w) and w >= 1 for w in widths):
                raise UserError(f"MapperConfig.{name} must be a tuple of integers >= 1, got {widths!r}")
        for name in ("latent", "batch_size", "epochs", "ae_epochs"):
            value = getattr(self, name)
            if not _is_int(value) or value < 1:
                raise UserError(f"MapperConfig.{name} must be an integer >= 1, got {value!r}")
        if not isinstance(self.batchnorm, bool):
            raise UserError(f"MapperConfig.batchnorm must be a bool, got {self.batchnorm!r}")
        for name in ("dropout", "ae_dropout"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise UserError(f"MapperConfig.{name} must be in [0, 1), got {getattr(self, name)!r}")
        if not self.lr > 0:
            raise UserError(f"MapperConfig.lr must be > 0, got {self.lr!r}")
        for name in ("weight_decay", "ae_weight_decay"):
            if not getattr(self, name) >= 0:
                raise UserError(f"MapperConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not _is_int(self.seed):
            raise UserError(f"MapperConfig.seed must be an integer, got {self.seed!r}")


def paper_config(kind: str, **overrides: Any) -> MapperConfig:
    """The paper's Table 8 settings for ``kind`` (DM: 500 epochs; SAM/TAM: 1000), then ``overrides``.

    For Fetch (Table 9) pass ``epochs=2000``.
    """
    epochs = get_kind(kind).paper_epochs or MapperConfig.epochs
    return MapperConfig(**{"kind": kind, "epochs": epochs, **overrides})


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
