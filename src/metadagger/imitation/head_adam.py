"""Adam steps of a linear head on fixed features, with the gradients written out by hand.

A head-only fit (the pairs', the evaluations', every DAgger round on pi*'s trunk) takes thousands
of steps on batches of ten 64-wide feature rows, where autograd's graph building,
``torch.optim.Adam``'s bookkeeping and Python's dispatch of each small operation cost several
times the arithmetic. :class:`LinearHeadAdam` calls the same ATen kernels in the same order as
``loss.backward()`` followed by the fused Adam step of :func:`metadagger.utils.optim.adam`, so
the weights it produces are equal to the bit (tests/imitation/test_head_adam.py checks it). A whole
epoch of steps runs in one TorchScript function: the interpreter dispatches each kernel without
Python, which halves the time per step again and changes no number (docs/performance.md).
"""

from __future__ import annotations

import functools
import warnings
from typing import Callable

import torch
from torch import nn

from metadagger.utils.optim import fused_adam_step


def _adam_steps(
    params: torch.Tensor,
    grad: torch.Tensor,
    exp_avg: torch.Tensor,
    exp_avg_sq: torch.Tensor,
    inputs: torch.Tensor,
    targets: torch.Tensor,
    order: torch.Tensor,
    batch_size: int,
    out_dim: int,
    lr: float,
    weight_decay: float,
    discrete: bool,
    step_t: torch.Tensor,
) -> torch.Tensor:
    """Adam steps on consecutive batches of ``order`` (rows of ``inputs`` and ``targets``), updating
    ``params`` (the head's weight, then its bias, flat), the moments and the step count ``step_t`` in
    place; returns each batch's loss before its step. Compiled by TorchScript (:func:`_compiled_adam_steps`)."""
    mean = 1  # ATen's reduction code for "mean" (a local: TorchScript reads no module globals)
    n_weight = params.numel() - out_dim
    weight = params[:n_weight].view(out_dim, -1)
    bias = params[n_weight:]
    grad_weight = grad[:n_weight].view(out_dim, -1)
    grad_bias = grad[n_weight:]
    weight_t = weight.t()
    one = torch.ones(())
    n_batches = (order.numel() + batch_size - 1) // batch_size
    losses = torch.empty(n_batches)
    for i in range(n_batches):
        rows = order[i * batch_size : (i + 1) * batch_size]
        features, labels = inputs[rows], targets[rows]
        outputs = torch.addmm(bias, features, weight_t)
        if discrete:
            log_probs = torch.log_softmax(outputs, 1)
            loss, total_weight = torch.ops.aten.nll_loss_forward(log_probs, labels, None, mean, -100)
            grad_log_probs = torch.ops.aten.nll_loss_backward(one, log_probs, labels, None, mean, -100, total_weight)
            grad_outputs = torch.ops.aten._log_softmax_backward_data(grad_log_probs, log_probs, 1, log_probs.dtype)
        else:
            loss = torch.ops.aten.mse_loss(outputs, labels, mean)
            grad_outputs = torch.ops.aten.mse_loss_backward(one, outputs, labels, mean)
        torch.mm(grad_outputs.t(), features, out=grad_weight)
        torch.sum(grad_outputs, [0], out=grad_bias)
        step_t.add_(1)
        fused_adam_step(params, grad, exp_avg, exp_avg_sq, step_t, lr, weight_decay)
        losses[i] = loss
    return losses


@functools.cache
def _compiled_adam_steps() -> Callable[..., torch.Tensor]:
    """:func:`_adam_steps` compiled once per process, on first use (not at import)."""
    with warnings.catch_warnings():
        # torch 2.13 marks TorchScript deprecated in favour of torch.compile, which needs a C++
        # toolchain at run time and many seconds per process to compile; constraints.txt pins torch.
        warnings.simplefilter("ignore", DeprecationWarning)
        return torch.jit.script(_adam_steps)


class LinearHeadAdam:
    """Adam on the weight and bias of ``head``, fed features that need no gradient.

    Args:
        head: the layer to train in place (both parameters trainable, float32).
        lr: Adam learning rate.
        weight_decay: Adam's L2 term (added to the gradient, as ``torch.optim.Adam`` does).
        discrete: cross-entropy on class indices; else mean squared error on vectors.
    """

    def __init__(self, head: nn.Linear, *, lr: float, weight_decay: float, discrete: bool):
        self.head, self.lr, self.weight_decay, self.discrete = head, float(lr), float(weight_decay), discrete
        # one flat buffer each for the parameters, their gradient and Adam's two moments: Adam is
        # elementwise, so updating the weight and bias together is the same arithmetic in half the calls
        self._params = torch.cat([head.weight.detach().reshape(-1), head.bias.detach()])
        self._grad = torch.empty_like(self._params)
        self._exp_avg = torch.zeros_like(self._params)
        self._exp_avg_sq = torch.zeros_like(self._params)
        self._step = torch.zeros(())  # Adam's step count, a float tensor as the fused kernel reads it

    @staticmethod
    def supports(head: nn.Module) -> bool:
        """Whether ``head`` is a float32 ``nn.Linear`` with both parameters trainable."""
        return (
            isinstance(head, nn.Linear)
            and head.bias is not None
            and head.weight.dtype == torch.float32
            and head.weight.requires_grad
            and head.bias.requires_grad
        )

    @torch.no_grad()
    def steps(
        self, features: torch.Tensor, targets: torch.Tensor, order: torch.Tensor, batch_size: int
    ) -> torch.Tensor:
        """One Adam step per batch of ``batch_size`` consecutive rows of ``order`` (the last batch
        may be smaller); returns each batch's loss before its step."""
        losses = _compiled_adam_steps()(
            self._params,
            self._grad,
            self._exp_avg,
            self._exp_avg_sq,
            features,
            targets,
            order,
            batch_size,
            self.head.out_features,
            self.lr,
            self.weight_decay,
            self.discrete,
            self._step,
        )
        return losses

    @torch.no_grad()
    def write_back(self) -> None:
        """Copy the trained weight and bias into ``head``."""
        n_weight = self.head.weight.numel()
        self.head.weight.copy_(self._params[:n_weight].view_as(self.head.weight))
        self.head.bias.copy_(self._params[n_weight:])
