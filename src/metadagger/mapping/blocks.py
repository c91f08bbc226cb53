"""The fully-connected block of the paper's mapping networks (appendix 7.1, Fig. 6).

A block is ``Linear -> [BatchNorm1d] -> LeakyReLU -> [Dropout]``; the grey BatchNorm and Dropout
boxes of Fig. 6 are switchable because the paper tunes or removes them per model. Weights are
Xavier-uniform and biases zero (Tables 8 and 9), drawn from an explicit generator.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["block", "init_linear", "mlp"]


def init_linear(layer: nn.Linear, generator: torch.Generator | None = None) -> None:
    """Xavier-uniform weight and zero bias, in place (the paper's initialisation)."""
    nn.init.xavier_uniform_(layer.weight, generator=generator)
    nn.init.zeros_(layer.bias)


def block(
    in_dim: int, out_dim: int, *, batchnorm: bool, dropout: float, generator: torch.Generator | None = None
) -> nn.Sequential:
    """One hidden block of Fig. 6: ``Linear -> [BatchNorm1d] -> LeakyReLU -> [Dropout]``.

    Args:
        in_dim: input width.
        out_dim: output width.
        batchnorm: insert a BatchNorm1d after the linear layer.
        dropout: drop probability in ``[0, 1)``; 0 leaves the Dropout layer out.
        generator: draws the initial weights; None uses torch's global generator.
    """
    _check_dims(in_dim=in_dim, out_dim=out_dim)
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout must be in [0, 1), got {dropout!r}")
    linear = nn.Linear(in_dim, out_dim)
    init_linear(linear, generator)
    layers: list[nn.Module] = [linear]
    if batchnorm:
        layers.append(nn.BatchNorm1d(out_dim))
    layers.append(nn.LeakyReLU())
    if dropout > 0:
        layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


def mlp(
    in_dim: int,
    hidden: Sequence[int],
    out_dim: int,
    *,
    batchnorm: bool,
    dropout: float,
    generator: torch.Generator | None = None,
) -> nn.Sequential:
    """A stack of :func:`block` s ending in a plain linear layer (no activation on the output).

    Args:
        in_dim: input width.
        hidden: widths of the hidden blocks; empty gives a single linear layer.
        out_dim: output width.
        batchnorm: BatchNorm in every hidden block.
        dropout: Dropout probability in every hidden block.
        generator: draws the initial weights, so the same seed gives the same network.
    """
    widths = [in_dim, *hidden]
    _check_dims(in_dim=in_dim, out_dim=out_dim, **{f"hidden[{i}]": h for i, h in enumerate(hidden)})
    layers: list[nn.Module] = [
        block(a, b, batchnorm=batchnorm, dropout=dropout, generator=generator) for a, b in zip(widths[:-1], widths[1:])
    ]
    head = nn.Linear(widths[-1], out_dim)
    init_linear(head, generator)
    layers.append(head)
    return nn.Sequential(*layers)


def _check_dims(**dims: int) -> None:
    for name, value in dims.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
