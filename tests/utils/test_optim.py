"""Every Adam metadagger trains with is utils.optim.adam, whose fused kernel's square roots do not
depend on the CPU (docs/architecture.md, "Adam's square root")."""

from __future__ import annotations

import re
from pathlib import Path

import torch

from metadagger.utils.optim import adam

SRC = Path(__file__).resolve().parents[2] / "src" / "metadagger"


def test_no_module_builds_torchs_default_adam():
    """torch.optim.Adam's default CPU path takes MKL's square roots, which differ by CPU."""
    direct = [
        str(path.relative_to(SRC))
        for path in SRC.rglob("*.py")
        if path.name != "optim.py" and re.search(r"optim\.Adam\(|optim\.AdamW\(", path.read_text())
    ]
    assert direct == []


def test_adam_is_torchs_fused_adam_with_its_defaults():
    weight = torch.nn.Parameter(torch.ones(3))
    optimizer = adam([weight], lr=1e-3, weight_decay=0.5)
    group = optimizer.param_groups[0]
    assert group["fused"] is True and group["lr"] == 1e-3 and group["weight_decay"] == 0.5
    assert group["betas"] == (0.9, 0.999) and group["eps"] == 1e-8 and not group["amsgrad"]
    weight.grad = torch.tensor([1.0, -2.0, 0.0])
    optimizer.step()
    # the first step moves each weight by lr against the sign of its gradient plus 0.5 x its weight
    assert torch.allclose(weight.detach(), torch.tensor([1 - 1e-3, 1 + 1e-3, 1 - 1e-3]), atol=1e-6)


def test_a_gradient_laid_out_otherwise_steps_the_weights_it_belongs_to():
    """torch.autograd.grad gives a convolution's weight gradient channels-last; the fused kernel
    must still pair each gradient element with its own weight."""
    conv = torch.nn.Conv2d(3, 4, 3)
    x = torch.randn(2, 3, 8, 8, generator=torch.Generator().manual_seed(0))
    (grad,) = torch.autograd.grad(conv(x).square().sum(), [conv.weight])
    channels_last = grad.to(memory_format=torch.channels_last)
    assert channels_last.stride() != conv.weight.stride()
    steps = []
    for given in (grad.contiguous(), channels_last):
        weight = torch.nn.Parameter(conv.weight.detach().clone())
        weight.grad = given
        adam([weight], lr=1e-2).step()
        steps.append(weight.detach())
    assert torch.equal(steps[0], steps[1])
