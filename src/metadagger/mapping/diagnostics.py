"""Does a mapper learn anything? The yardsticks of the mapping diagnostics (docs/diagnostics.md).

Heads are flat vectors of layer n (weight ``[outputs, features]`` then bias ``[outputs]``).

- :func:`canonical_heads`: a discrete head's rows minus their mean over classes (and the bias
  minus its mean): adding one vector to every row of a softmax head changes no action, so that
  shift is removed before any weight-space number.
- :func:`function_error`: on trunk features of a seed's DAgger states, the share of states where
  two heads choose different classes, or the mean squared difference of their actions.
- :func:`memorisation`: how much nearer a prediction is to some training w_DA than to its own.
- :func:`pairwise_spread`: the mean distance between heads that differ only by their fits' seeds
  (the noise ceiling).
"""

from __future__ import annotations

import itertools

import torch

from metadagger.imitation.head_fits import head_outputs, split_head

__all__ = ["canonical_heads", "function_error", "head_outputs", "memorisation", "pairwise_spread", "weight_error"]


def canonical_heads(heads: torch.Tensor, outputs: int) -> torch.Tensor:
    """Discrete heads ``[..., d]`` with the softmax's free shift removed (each weight column and
    the bias centred over the ``outputs`` classes)."""
    weight, bias = split_head(heads, outputs)
    weight = weight - weight.mean(dim=-2, keepdim=True)
    bias = bias - bias.mean(dim=-1, keepdim=True)
    return torch.cat([weight.flatten(-2), bias], dim=-1)


def weight_error(predicted: torch.Tensor, truth: torch.Tensor, *, outputs: int, discrete: bool) -> torch.Tensor:
    """Per row, the mean squared difference of two heads ``[N, d]`` (canonical if ``discrete``)."""
    if discrete:
        predicted, truth = canonical_heads(predicted, outputs), canonical_heads(truth, outputs)
    return (predicted - truth).pow(2).mean(dim=-1)


def function_error(
    predicted: torch.Tensor, truth: torch.Tensor, features: torch.Tensor, *, outputs: int, discrete: bool
) -> float:
    """On ``features`` ``[S, F]``: the share of states where two heads choose different classes
    (``discrete``), or the mean squared difference of their actions."""
    a, b = head_outputs(predicted, features, outputs), head_outputs(truth, features, outputs)
    if discrete:
        return float((a.argmax(dim=-1) != b.argmax(dim=-1)).to(torch.float64).mean())
    return float((a - b).pow(2).mean())


def memorisation(predicted: torch.Tensor, truth: torch.Tensor, train_targets: torch.Tensor) -> torch.Tensor:
    """Per validation row: distance to the nearest training w_DA over distance to its own w_DA
    (near 0: the prediction is a training example; rows ``[N, d]``, ``[N, d]``, ``[M, d]``)."""
    # each pair rooted on its own (the CPU's correctly rounded root), not by MKL's vector math
    distances = torch.cdist(
        predicted.to(torch.float64), train_targets.to(torch.float64), compute_mode="donot_use_mm_for_euclid_dist"
    )
    nearest = distances.min(dim=1).values
    own = (predicted - truth).to(torch.float64).norm(dim=1)
    return nearest / own.clamp_min(1e-12)


def pairwise_spread(
    heads: torch.Tensor, features: torch.Tensor, *, outputs: int, discrete: bool
) -> tuple[float, float]:
    """Mean over pairs of ``heads`` ``[M, d]`` (M >= 2) of their weight-space and function-space errors."""
    if len(heads) < 2:
        raise ValueError(f"a spread needs at least 2 heads, got {len(heads)}")
    pairs = list(itertools.combinations(range(len(heads)), 2))
    weight = sum(
        float(weight_error(heads[i : i + 1], heads[j : j + 1], outputs=outputs, discrete=discrete)) for i, j in pairs
    )
    function = sum(function_error(heads[i], heads[j], features, outputs=outputs, discrete=discrete) for i, j in pairs)
    return weight / len(pairs), function / len(pairs)
