"""The one Adam metadagger trains with: torch's fused CPU kernel.

``torch.optim.Adam``'s default CPU path computes its denominator with ``Tensor.sqrt``, which ATen
hands to MKL's vector math library; those square roots are not correctly rounded, and which of them
are off by a unit in the last place depends on the CPU (an Intel Xeon and an AMD EPYC part, even
under ``MKL_CBWR=COMPATIBLE``; docs/determinism.md, "Kernels no variable pins"). The fused kernel takes
the square root with the CPU's own correctly rounded instruction, in ATen's vector code that
:mod:`metadagger.utils.kernels` pins, so an Adam step gives the same bits on every x86-64 CPU.

The fused kernel walks a parameter and its gradient in memory order, so a gradient laid out
otherwise (``torch.autograd.grad`` returns a convolution's weight gradient channels-last) would be
paired with the wrong weights; :func:`adam` lays every gradient out as its parameter first.
"""

from __future__ import annotations

from typing import Any, Iterable

import torch


def _lay_out_gradients_as_parameters(optimizer: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
    for group in optimizer.param_groups:
        for param in group["params"]:
            if param.grad is not None and param.grad.stride() != param.stride():
                param.grad = torch.empty_like(param).copy_(param.grad)


def fused_adam_step(
    params: torch.Tensor,
    grad: torch.Tensor,
    exp_avg: torch.Tensor,
    exp_avg_sq: torch.Tensor,
    step: torch.Tensor,
    lr: float,
    weight_decay: float,
) -> None:
    """One step of the fused kernel on contiguous ``params`` (``torch.optim.Adam``'s defaults
    otherwise), updating ``params`` and the moments in place; ``step`` (a float tensor) is the
    step's count, from 1. The hand-written head fits call it inside TorchScript, which compiles it
    with them; it takes the functional form, since TorchScript drops the in-place one, whose only
    effect is on its lists' tensors."""
    new_params, _, new_exp_avg, new_exp_avg_sq, _ = torch.ops.aten._fused_adam(
        [params],
        [grad],
        [exp_avg],
        [exp_avg_sq],
        [],
        [step],
        lr=lr,
        beta1=0.9,
        beta2=0.999,
        weight_decay=weight_decay,
        eps=1e-8,
        amsgrad=False,
        maximize=False,
    )
    params.copy_(new_params[0])
    exp_avg.copy_(new_exp_avg[0])
    exp_avg_sq.copy_(new_exp_avg_sq[0])


def adam(params: Iterable[torch.Tensor], *, lr: float, weight_decay: float = 0.0) -> torch.optim.Adam:
    """``torch.optim.Adam`` with its defaults otherwise, on the fused kernel."""
    optimizer = torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, fused=True)
    optimizer.register_step_pre_hook(_lay_out_gradients_as_parameters)
    return optimizer
