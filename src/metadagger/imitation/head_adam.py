"""Adam steps of a linear head on fixed features, with the gradients written out by hand.

A head-only fit (the pairs', the evaluations', every DAgger round on pi*'s trunk) takes thousands
of steps on batches of ten 64-wide feature rows, where autograd's graph building and
``torch.optim.Adam``'s bookkeeping cost several times the arithmetic. :class:`LinearHeadAdam`
calls the same ATen kernels in the same order as ``loss.backward()`` followed by
``torch.optim.Adam.step()`` (single-tensor, no amsgrad), so the weights it produces are equal to the
bit (tests/imitation/test_head_adam.py checks it), at about a third of the time per step.
"""

from __future__ import annotations

import torch
from torch import nn

# torch.optim.Adam's defaults, which fit_bc uses
_BETA1, _BETA2, _EPS = 0.9, 0.999, 1e-8
_MEAN = 1  # ATen's reduction code for "mean"


class LinearHeadAdam:
    """Adam on the weight and bias of ``head``, fed features that need no gradient.

    Args:
        head: the layer to train in place (both parameters trainable, float32).
        lr: Adam learning rate.
        weight_decay: Adam's L2 term (added to the gradient, as ``torch.optim.Adam`` does).
        discrete: cross-entropy on class indices; else mean squared error on vectors.
    """

    def __init__(self, head: nn.Linear, *, lr: float, weight_decay: float, discrete: bool):
        self.head, self.lr, self.weight_decay, self.discrete = head, lr, weight_decay, discrete
        out_dim, in_dim = head.weight.shape
        n_weight = out_dim * in_dim
        # one flat buffer each for the parameters, their gradient and Adam's two moments: Adam is
        # elementwise, so updating the weight and bias together is the same arithmetic in half the calls
        self._params = torch.cat([head.weight.detach().reshape(-1), head.bias.detach()])
        self._grad = torch.empty_like(self._params)
        self._exp_avg = torch.zeros_like(self._params)
        self._exp_avg_sq = torch.zeros_like(self._params)
        self._weight, self._bias = self._params[:n_weight].view(out_dim, in_dim), self._params[n_weight:]
        self._grad_weight, self._grad_bias = self._grad[:n_weight].view(out_dim, in_dim), self._grad[n_weight:]
        self._weight_t = self._weight.t()
        self._one = torch.ones(())
        self._steps = 0

    @staticmethod
    def supports(head: nn.Module) -> bool:
        """Whether ``head`` is a float32 ``nn.Linear`` with both parameters trainable."""
        return (isinstance(head, nn.Linear) and head.bias is not None and head.weight.dtype == torch.float32
                and head.weight.requires_grad and head.bias.requires_grad)

    @torch.no_grad()
    def step(self, features: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """One Adam step on a batch; returns the batch's loss (before the step)."""
        outputs = torch.addmm(self._bias, features, self._weight_t)
        if self.discrete:
            log_probs = torch.log_softmax(outputs, 1)
            loss, total_weight = torch.ops.aten.nll_loss_forward(log_probs, targets, None, _MEAN, -100)
            grad_log_probs = torch.ops.aten.nll_loss_backward(self._one, log_probs, targets, None, _MEAN, -100, total_weight)
            grad_outputs = torch.ops.aten._log_softmax_backward_data(grad_log_probs, log_probs, 1, log_probs.dtype)
        else:
            loss = torch.ops.aten.mse_loss(outputs, targets, _MEAN)
            grad_outputs = torch.ops.aten.mse_loss_backward(self._one, outputs, targets, _MEAN)
        torch.mm(grad_outputs.t(), features, out=self._grad_weight)
        torch.sum(grad_outputs, 0, out=self._grad_bias)
        grad = self._grad if self.weight_decay == 0 else self._grad.add(self._params, alpha=self.weight_decay)
        self._steps += 1
        self._exp_avg.lerp_(grad, 1 - _BETA1)
        self._exp_avg_sq.mul_(_BETA2).addcmul_(grad, grad, value=1 - _BETA2)
        step_size = self.lr / (1 - _BETA1**self._steps)
        denom = (self._exp_avg_sq.sqrt() / ((1 - _BETA2**self._steps) ** 0.5)).add_(_EPS)
        self._params.addcdiv_(self._exp_avg, denom, value=-step_size)
        return loss

    @torch.no_grad()
    def write_back(self) -> None:
        """Copy the trained weight and bias into ``head``."""
        self.head.weight.copy_(self._weight)
        self.head.bias.copy_(self._bias)
