"""LinearHeadAdam gives the weights of autograd + torch.optim.Adam to the bit, a step or an epoch per call."""

from __future__ import annotations

import copy

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from metadagger.imitation.head_adam import LinearHeadAdam
from metadagger.utils.optim import adam


def _reference(
    head: nn.Linear,
    x: torch.Tensor,
    y: torch.Tensor,
    batches: list[torch.Tensor],
    lr: float,
    weight_decay: float,
    discrete: bool,
) -> list[float]:
    optimizer = adam(head.parameters(), lr=lr, weight_decay=weight_decay)
    losses = []
    for batch in batches:
        out = head(x[batch])
        loss = F.cross_entropy(out, y[batch]) if discrete else F.mse_loss(out, y[batch])
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return losses


@pytest.mark.parametrize("per_call", ["step", "epoch"])
@pytest.mark.parametrize("discrete", [True, False])
@pytest.mark.parametrize("weight_decay", [0.0, 1e-3])
def test_same_weights_and_losses_as_autograd_adam(discrete: bool, weight_decay: float, per_call: str) -> None:
    gen = torch.Generator().manual_seed(1)
    n, width, outputs = 203, 64, 20 if discrete else 3  # 203: the last batch is partial
    x = torch.randn(n, width, generator=gen).relu()
    y = torch.randint(0, outputs, (n,), generator=gen) if discrete else torch.randn(n, outputs, generator=gen)
    head = nn.Linear(width, outputs)
    orders = [torch.randperm(n, generator=torch.Generator().manual_seed(seed)) for seed in range(5)]
    batches = [order[s : s + 10] for order in orders for s in range(0, n, 10)]  # five epochs' worth of steps
    initial = head.weight.detach().clone()
    expected = copy.deepcopy(head)
    expected_losses = _reference(expected, x, y, batches, 1e-3, weight_decay, discrete)

    adam = LinearHeadAdam(head, lr=1e-3, weight_decay=weight_decay, discrete=discrete)
    if per_call == "step":
        losses = [adam.steps(x, y, batch, len(batch)).item() for batch in batches]
    else:  # a whole epoch of steps in one call, as fit_bc takes them
        losses = [loss for order in orders for loss in adam.steps(x, y, order, 10).tolist()]
    adam.write_back()

    assert losses == expected_losses
    assert torch.equal(head.weight, expected.weight) and torch.equal(head.bias, expected.bias)
    assert not torch.equal(head.weight, initial)  # it did train


def test_supports_only_a_trainable_float_linear_layer() -> None:
    assert LinearHeadAdam.supports(nn.Linear(4, 2))
    assert not LinearHeadAdam.supports(nn.Linear(4, 2, bias=False))
    assert not LinearHeadAdam.supports(nn.Sequential(nn.Linear(4, 2)))
    frozen = nn.Linear(4, 2)
    frozen.bias.requires_grad_(False)
    assert not LinearHeadAdam.supports(frozen)
    assert not LinearHeadAdam.supports(nn.Linear(4, 2).double())
