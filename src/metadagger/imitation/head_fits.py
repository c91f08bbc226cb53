"""Many head-only fits as one batched problem: the refits of every lane at once.

A head-only fit (:func:`~metadagger.imitation.bc.fit_bc` with ``head_only``) takes thousands of
Adam steps on batches of ten feature rows, each step a dozen kernels too small to keep a core
busy. :func:`fit_heads` steps many heads together instead: at step ``t`` every head takes the
``t``-th step of its own fit (its own data, its own batch order, its own number of steps), all
of them in one batched matrix product, one softmax and one fused Adam update (ATen's, as the
one-head path takes: only kernels whose bits do not depend on the CPU, docs/determinism.md).

Every head's batch has the fit's ``batch_size`` rows, a short last batch padded with zero rows
that a mask takes out of the loss; a head whose fit has ended keeps its weights. At this fixed
shape a head's arithmetic does not depend on the heads beside it, nor on how many there are
(tests/imitation/test_head_fits.py checks it), so a fit gives the same head whichever fits share
its batch. The numbers are not bit-equal to the one-head kernel
(:class:`~metadagger.imitation.head_adam.LinearHeadAdam`): the loss is a masked sum over the
padded batch, not ATen's mean over a batch of its own size.

A fit may carry a Gaussian prior (:class:`HeadFit.prior`): its loss is then the data's plus
``sum_j weight_j (w_j - mean_j)^2 / 2`` over the head's weights and biases, a pull toward a mean
head with a strength of its own per coordinate (docs/method.md, "A prior for the head"). The
losses reported are the data's alone.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence

import torch

from metadagger.errors import DivergedError, check_finite_loss
from metadagger.utils.device import compute_device
from metadagger.utils.optim import fused_adam_step


@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on a head: the mean it pulls toward and the pull on each coordinate."""

    mean: torch.Tensor
    """Flat float32, laid out as the head (weight rows, then bias)."""
    weight: torch.Tensor
    """Flat float32, >= 0: the strength times each coordinate's precision."""
    pinned: bool = False
    """At the prior's limit (an infinite strength): the fit takes no step and returns the mean."""


@dataclass(frozen=True)
class HeadFit:
    """One head-only fit, as :func:`~metadagger.imitation.bc.fit_bc` would run it."""

    head: torch.Tensor
    """The starting head, flat float32 (weight rows, then bias: ``Policy.head_vector``)."""
    features: torch.Tensor
    """(N, feature_dim) float32 trunk features of the data."""
    targets: torch.Tensor
    """(N,) int64 class labels, or (N, out_dim) float32 vectors."""
    orders: torch.Tensor
    """(epochs, N) int64: each epoch's permutation of the rows (the fit's seeded shuffles)."""
    lr: float
    """Adam learning rate."""
    weight_decay: float
    """Adam's L2 term."""
    batch_size: int
    """Rows per step."""
    called: str
    """How an error names this fit."""
    prior: Prior | None = None
    """A Gaussian prior the fit adds to its loss; None: none."""

    def __post_init__(self) -> None:
        if self.prior is not None and not (self.prior.mean.shape == self.prior.weight.shape == self.head.shape):
            raise ValueError(
                f"{self.called}: a prior's mean {tuple(self.prior.mean.shape)} and weight "
                f"{tuple(self.prior.weight.shape)} must be shaped as the head {tuple(self.head.shape)}"
            )


@dataclass(frozen=True)
class FittedHead:
    """What one fit of :func:`fit_heads` made."""

    head: torch.Tensor
    """The fitted head, flat float32."""
    losses: list[float]
    """Mean training loss of each epoch."""


#: ATen's fused Adam takes a tensor in units of this many floats (a cache line), each in vector code
#: but a last short one, whose tail it computes in scalar code that rounds otherwise. Every head is
#: padded to whole units, so each of its weights is updated by the same code wherever it lies.
_ADAM_UNIT = 16


def _batched_adam_steps(
    params: torch.Tensor,
    out_dim: int,
    exp_avg: torch.Tensor,
    exp_avg_sq: torch.Tensor,
    features: torch.Tensor,
    targets: torch.Tensor,
    rows: torch.Tensor,
    share: torch.Tensor,
    live: List[int],
    lr: float,
    weight_decay: float,
    discrete: bool,
    prior_mean: Optional[torch.Tensor],
    prior_weight: Optional[torch.Tensor],
) -> torch.Tensor:
    """Every head's steps, in lockstep, updating ``params``, ``exp_avg`` and ``exp_avg_sq`` in place.

    ``params`` is (B, P): each head's weight with its bias as a last column, (out_dim, d + 1) flat,
    which the ones column of ``features`` multiplies, then zeros up to P, a multiple of
    :data:`_ADAM_UNIT` (Adam's moments alike). Heads are ordered by their number of steps, longest
    first, so step ``t``'s heads are the first ``live[t]``; ``rows[t, b]`` are head ``b``'s rows of
    that step (indices into ``features`` and ``targets``; padding points at a zero row) and
    ``share[t, b]`` each row's weight in the batch's mean (0 for padding); ``prior_mean`` and
    ``prior_weight``, (B, out_dim, d + 1), a Gaussian prior's gradient ``weight * (w - mean)``
    (both None: no prior). Returns each step's per-row losses (T, B, batch), unweighted. Compiled
    by TorchScript (:func:`_compiled_steps`).
    """
    steps, n_heads, batch = rows.shape
    inputs = features.shape[1]
    size = out_dim * inputs
    row_losses = torch.zeros(steps, n_heads, batch, device=params.device)
    grads = torch.zeros_like(params)  # the padding's gradient stays 0, so its weights stay 0
    for t in range(steps):
        k = live[t]
        x = features[rows[t, :k]]  # (k, batch, d + 1)
        weight = params[:k, :size].view(k, out_dim, inputs)
        outputs = torch.bmm(x, weight.transpose(1, 2))  # (k, batch, out)
        if discrete:
            labels = targets[rows[t, :k]].unsqueeze(2)
            row_losses[t, :k] = torch.log_softmax(outputs, 2).gather(2, labels).squeeze(2).neg()
            # softmax, not exp of the log-probabilities: Tensor.exp is MKL's vector math, whose bits
            # depend on the CPU; ATen's softmax kernel is its own (docs/determinism.md)
            probs = torch.softmax(outputs, 2)
            grad_outputs = probs.scatter_add_(2, labels, torch.full(labels.shape, -1.0, device=params.device))
        else:
            grad_outputs = outputs - targets[rows[t, :k]]
            row_losses[t, :k] = (grad_outputs * grad_outputs).mean(2)
            grad_outputs = grad_outputs * (2.0 / outputs.shape[2])
        grad_outputs.mul_(share[t, :k].unsqueeze(2))
        grad = torch.bmm(grad_outputs.transpose(1, 2), x)
        if prior_mean is not None and prior_weight is not None:
            grad = grad.addcmul(prior_weight[:k], weight - prior_mean[:k])
        grads[:k, :size].copy_(grad.view(k, size))
        # ATen's fused Adam step, as the one-head path takes (utils/optim.py): its square root is the
        # CPU's correctly rounded one, where Tensor.sqrt's is MKL's. Every live head is at step t + 1.
        step = torch.full((), float(t + 1), device=params.device)
        fused_adam_step(params[:k], grads[:k], exp_avg[:k], exp_avg_sq[:k], step, lr, weight_decay)
    return row_losses


@functools.cache
def _compiled_steps() -> Callable[..., torch.Tensor]:
    """:func:`_batched_adam_steps` compiled once per process, on first use."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # as head_adam's: constraints.txt pins torch
        return torch.jit.script(_batched_adam_steps)


def fit_heads(fits: Sequence[HeadFit], *, out_dim: int, discrete: bool) -> list[FittedHead]:
    """Run ``fits`` as batched problems (one per learning rate, weight decay, batch size, and with
    or without a prior); their results in order.

    Raises:
        DivergedError: a fit's epoch loss or final weight is not finite (named by its ``called``).
    """
    out: list[FittedHead | None] = [None] * len(fits)
    groups: dict[tuple[float, float, int, bool], list[int]] = {}
    for i, fit in enumerate(fits):
        if fit.prior is not None and fit.prior.pinned:  # the limit of the prior: the mean itself
            out[i] = FittedHead(head=fit.prior.mean.to(torch.float32).clone(), losses=[])
            continue
        groups.setdefault((fit.lr, fit.weight_decay, fit.batch_size, fit.prior is not None), []).append(i)
    for (lr, weight_decay, batch_size, _), members in groups.items():
        heads = _fit_group([fits[i] for i in members], lr, weight_decay, batch_size, out_dim, discrete)
        for i, fitted in zip(members, heads):
            out[i] = fitted
    return out  # type: ignore[return-value]


def _fit_group(
    fits: list[HeadFit], lr: float, weight_decay: float, batch_size: int, out_dim: int, discrete: bool
) -> list[FittedHead]:
    """Fits that share their optimiser settings, stepped together (longest first)."""
    schedules = [_schedule(fit.orders, batch_size) for fit in fits]
    order = sorted(range(len(fits)), key=lambda b: -len(schedules[b][0]))  # stable: ties keep their order
    # one table of every fit's rows with a ones column (the bias's input), a zero row last for the padding
    sizes = [len(fits[b].features) for b in order]
    starts = [sum(sizes[:i]) for i in range(len(sizes))]
    pad = sum(sizes)
    table = torch.cat([*(fits[b].features for b in order), torch.zeros(1, fits[0].features.shape[1])])
    features = torch.cat([table, torch.ones(len(table), 1)], 1)
    features[pad, -1] = 0.0
    targets = torch.cat([*(fits[b].targets for b in order), torch.zeros_like(fits[0].targets[:1])])
    steps = len(schedules[order[0]][0])
    rows = torch.full((steps, len(fits), batch_size), pad, dtype=torch.long)
    share = torch.zeros(steps, len(fits), batch_size)
    for slot, (b, start) in enumerate(zip(order, starts)):
        fit_rows, fit_counts = schedules[b]
        real = torch.arange(batch_size).unsqueeze(0) < fit_counts.unsqueeze(1)
        rows[: len(fit_rows), slot] = torch.where(real, fit_rows + start, pad)
        share[: len(fit_rows), slot] = real.float() / fit_counts.unsqueeze(1).float()
    live = (share[:, :, 0] > 0).sum(1).tolist()  # step t's heads: every fit that has a step t
    device = compute_device()  # the whole problem on it; the heads and losses back on the CPU
    share = share.to(device)
    size = out_dim * features.shape[1]
    params = torch.zeros(len(fits), -(-size // _ADAM_UNIT) * _ADAM_UNIT)
    params[:, :size] = torch.stack([_with_bias_column(fits[b].head, out_dim).reshape(-1) for b in order])
    params = params.to(device)
    exp_avg, exp_avg_sq = torch.zeros_like(params), torch.zeros_like(params)
    prior_mean = prior_weight = None
    if fits[0].prior is not None:  # a group's fits all have one, or none has
        priors = [fits[b].prior for b in order]
        prior_mean = torch.stack([_with_bias_column(p.mean, out_dim) for p in priors]).to(device)  # type: ignore[union-attr]
        prior_weight = torch.stack([_with_bias_column(p.weight, out_dim) for p in priors]).to(device)  # type: ignore[union-attr]
    with torch.no_grad():
        row_losses = _compiled_steps()(
            params,
            out_dim,
            exp_avg,
            exp_avg_sq,
            features.to(device),
            (targets if discrete else targets.to(torch.float32)).to(device),
            rows.to(device),
            share,
            live,
            float(lr),
            float(weight_decay),
            discrete,
            prior_mean,
            prior_weight,
        )
    step_losses = (row_losses * share).sum(2).cpu()  # (T, B): each step's mean loss
    params = params.cpu()
    fitted: list[FittedHead | None] = [None] * len(fits)
    for slot, b in enumerate(order):
        n_steps = len(schedules[b][0])
        weight = params[slot, :size].view(out_dim, -1)
        head = torch.cat([weight[:, :-1].reshape(-1), weight[:, -1]])
        fitted[b] = _finish(fits[b], head, step_losses[:n_steps, slot], schedules[b][1])
    return fitted  # type: ignore[return-value]


def split_head(heads: torch.Tensor, outputs: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat heads ``[..., d]`` (weight rows, then bias) as weights ``[..., outputs, F]`` and biases."""
    if heads.shape[-1] % outputs or heads.shape[-1] <= outputs:
        raise ValueError(
            f"a head of length {heads.shape[-1]} is not a layer with {outputs} outputs (weights then biases)"
        )
    features = heads.shape[-1] // outputs - 1
    weight = heads[..., : outputs * features].reshape(*heads.shape[:-1], outputs, features)
    return weight, heads[..., outputs * features :]


def head_outputs(head: torch.Tensor, features: torch.Tensor, outputs: int) -> torch.Tensor:
    """A flat head's outputs ``[S, outputs]`` on trunk ``features`` ``[S, F]``: class logits or the action."""
    weight, bias = split_head(head, outputs)
    return features @ weight.T + bias


def _with_bias_column(head: torch.Tensor, out_dim: int) -> torch.Tensor:
    """A flat head (weight rows, then bias) as (out_dim, d + 1), the bias the last column."""
    head = head.to(torch.float32)
    n_weight = head.numel() - out_dim
    return torch.cat([head[:n_weight].view(out_dim, -1), head[n_weight:].unsqueeze(1)], 1)


def _schedule(orders: torch.Tensor, batch_size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A fit's steps: (steps, batch_size) row indices (a short last batch of an epoch repeats its
    first rows, masked out), and each step's count of real rows."""
    epochs, n = orders.shape
    per_epoch = -(-n // batch_size)
    padded = torch.zeros((epochs, per_epoch * batch_size), dtype=torch.long)
    padded[:, :n] = orders
    counts = torch.full((per_epoch,), batch_size, dtype=torch.long)
    counts[-1] = n - (per_epoch - 1) * batch_size
    return padded.view(epochs * per_epoch, batch_size), counts.repeat(epochs)


def _finish(fit: HeadFit, head: torch.Tensor, step_losses: torch.Tensor, counts: torch.Tensor) -> FittedHead:
    """The fit's epoch losses (each a mean over its rows), checked finite, and its head."""
    epochs, n = fit.orders.shape
    weighted = (step_losses.double() * counts.double()).view(epochs, -1).sum(1) / n
    losses = weighted.tolist()
    fix = f"lower its learning rate (now {fit.lr:g}) or check its data"
    for epoch, loss in enumerate(losses):
        check_finite_loss(loss, called=fit.called, epoch=epoch + 1, epochs=epochs, fix=fix)
    if not bool(torch.isfinite(head).all()):
        raise DivergedError(f"{fit.called} diverged: its weights are not finite after {epochs} epochs; {fix}")
    return FittedHead(head=head.clone(), losses=losses)
