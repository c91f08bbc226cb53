"""Behavioural cloning: a supervised fit of a policy to (observation, expert label) pairs.

With ``head_only=True`` the trunk stays fixed, so its features are computed once per image
(:class:`FeatureCache`) and only layer n is fitted on them: the cheap fit MetaL DAgger repeats
for every seed and every DAgger round.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
import torch.nn.functional as F
from torch.nn.utils import parameters_to_vector

from metadagger.errors import DivergedError, UserError, check_finite_loss
from metadagger.imitation.data import Aggregate, Dataset
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.head_adam import LinearHeadAdam
from metadagger.imitation.head_fits import HeadFit
from metadagger.imitation.image_rows import ImageRows
from metadagger.imitation.selection import EpochSelector
from metadagger.policies import Policy, load_policy
from metadagger.utils.device import compute_device
from metadagger.utils.optim import adam
from metadagger.utils.progress import progress_bar
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT

#: How a seed's fresh head starts (:attr:`BCConfig.head_init`).
HEAD_INITS = ("seed", "shared")
#: How a whole-policy fit's learning rate moves over its epochs (:attr:`BCConfig.lr_schedule`).
LR_SCHEDULES = ("constant", "cosine")


#: Where a DAgger refit may start (:attr:`BCConfig.refit_from`).
REFIT_FROM = ("current", "origin")


@dataclass(frozen=True)
class BCConfig:
    """How one behavioural-cloning fit runs (defaults follow the paper's Table 8)."""

    lr: float = 1e-4
    """Adam learning rate."""
    batch_size: int = 10
    """Samples per gradient step."""
    epochs: int = 50
    """Passes over the dataset."""
    weight_decay: float = 0.0
    """Adam weight decay (L2)."""
    head_only: bool = False
    """Fit layer n only, on cached trunk features; the trunk is left unchanged."""
    seed: int = 0
    """Seed of the shuffling order (and of the augmentation's shifts)."""
    augment_shift: int = 0
    """Image augmentation of whole-policy fits: every sample of every batch is shifted by up to
    this many pixels in x and y (each offset uniform in ``[-augment_shift, augment_shift]``), the
    uncovered border filled by repeating the edge pixels, as DrQ does (Kostrikov et al. 2020: pad
    and random crop). Offsets come from the fit's seeded generator, so fits stay deterministic.
    0 (the default) turns it off and leaves the fit exactly as without it. Head-only fits train
    on cached trunk features, which cannot be augmented, so they need 0."""
    head_init: str = field(default="seed", metadata=STAMPED_UNLESS_DEFAULT)
    """How the fresh head of a seed's head-only BC fit (the pairs', the evaluations') starts:
    ``seed``, Xavier drawn from the env seed (the paper's); ``shared``, one Xavier draw (seed 0)
    for every seed, so that heads differ between seeds only by what their data taught them
    (docs/families.md)."""
    lr_schedule: str = field(default="constant", metadata=STAMPED_UNLESS_DEFAULT)
    """Whole-policy fits: ``constant`` keeps ``lr`` for every epoch; ``cosine`` anneals it over
    the epochs, epoch e (from 0) taking ``lr * (1 + cos(pi * e / epochs)) / 2``, so a fit ends
    with small steps instead of swinging between policies (docs/fetch.md). Head-only fits need
    ``constant``."""
    batch_shards: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """Whole-policy fits: each batch's gradient is computed in this many contiguous parts, each
    in its own thread, and the parts' gradients are summed in a fixed order. The arithmetic
    depends on this number alone, never on the cores there are, so a fit with 2 shards gives the
    same weights on one core as on two, where it runs about twice as fast. 1 (the default) is the
    plain autograd step. Head-only fits need 1: their steps are microseconds
    (docs/performance.md)."""

    refit_from: str = field(default="current", metadata=STAMPED_UNLESS_DEFAULT)
    """Read by DAgger's refits only (``pairs.dagger_bc``, ``mdi.dagger_bc``): where each round's
    refit on the aggregated data starts. ``current``: the head the round rolled out, continued
    with a fresh Adam. ``origin``: the head the seed's fits began from (the seed's fresh head for
    DAgger from BC, so that every refit is BC on the aggregate, as DAgger retrains; the saved
    initialisation for DAgger-MDI). Continuing at a large rate can lose what BC had
    (docs/fetch.md, "Refits that keep what BC had")."""

    def lr_at(self, epoch: int) -> float:
        """The learning rate of epoch ``epoch`` (counted from 0) under :attr:`lr_schedule`."""
        if self.lr_schedule == "constant":
            return self.lr
        return self.lr * (1 + math.cos(math.pi * epoch / self.epochs)) / 2

    def head_init_seed(self, seed: int) -> int:
        """The seed of the initial head of env seed ``seed``'s fit."""
        return seed if self.head_init == "seed" else 0

    def __post_init__(self) -> None:
        if not self.lr > 0:
            raise UserError(f"BCConfig.lr must be > 0, got {self.lr}")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise UserError(f"BCConfig.batch_size must be an integer >= 1, got {self.batch_size!r}")
        if not isinstance(self.epochs, int) or self.epochs < 1:
            raise UserError(f"BCConfig.epochs must be an integer >= 1, got {self.epochs!r}")
        if not self.weight_decay >= 0:
            raise UserError(f"BCConfig.weight_decay must be >= 0, got {self.weight_decay}")
        if self.refit_from not in REFIT_FROM:
            raise UserError(f"BCConfig.refit_from must be one of {', '.join(REFIT_FROM)}, got {self.refit_from!r}")
        if not isinstance(self.seed, int):
            raise UserError(f"BCConfig.seed must be an integer, got {self.seed!r}")
        if not isinstance(self.augment_shift, int) or isinstance(self.augment_shift, bool) or self.augment_shift < 0:
            raise UserError(f"BCConfig.augment_shift must be an integer >= 0, got {self.augment_shift!r}")
        if self.head_init not in HEAD_INITS:
            raise UserError(f"BCConfig.head_init must be one of {', '.join(HEAD_INITS)}, got {self.head_init!r}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise UserError(f"BCConfig.lr_schedule must be one of {', '.join(LR_SCHEDULES)}, got {self.lr_schedule!r}")
        if self.lr_schedule != "constant" and self.head_only:
            raise UserError(
                "BCConfig.lr_schedule needs a whole-policy fit: head-only fits keep a constant rate; "
                "set lr_schedule=constant or head_only=false"
            )
        if not isinstance(self.batch_shards, int) or isinstance(self.batch_shards, bool) or self.batch_shards < 1:
            raise UserError(f"BCConfig.batch_shards must be an integer >= 1, got {self.batch_shards!r}")
        if self.batch_shards > 1 and self.head_only:
            raise UserError(
                "BCConfig.batch_shards needs a whole-policy fit: head-only steps are too small to split; set "
                "batch_shards=1 or head_only=false"
            )
        if self.augment_shift and self.head_only:
            raise UserError(
                "BCConfig.augment_shift needs a whole-policy fit: head-only fits use cached trunk features; set "
                "augment_shift=0 or head_only=false"
            )


def random_shift(obs: torch.Tensor, max_shift: int, generator: torch.Generator) -> torch.Tensor:
    """Images (N, H, W, C) each shifted by its own offsets in ``[-max_shift, max_shift]`` (x and y),
    border pixels repeated (edge padding then a random crop to the original size).

    The offsets are drawn from ``generator``; the dtype (uint8 images) is kept.
    """
    if max_shift == 0:
        return obs
    n, height, width = obs.shape[:3]
    offsets = torch.randint(-max_shift, max_shift + 1, (n, 2), generator=generator)
    rows = (torch.arange(height)[None, :] + offsets[:, :1]).clamp_(0, height - 1)
    cols = (torch.arange(width)[None, :] + offsets[:, 1:]).clamp_(0, width - 1)
    return obs[torch.arange(n)[:, None, None], rows[:, :, None], cols[:, None, :]]


def check_data(policy: Policy, data: Dataset | Aggregate) -> None:
    """Raise a :class:`~metadagger.errors.UserError` unless ``policy`` can be fitted on ``data``."""
    arch = policy.arch
    if len(data) == 0:
        raise UserError("cannot fit on an empty dataset: collect at least one demonstration first")
    if list(data.image_shape) != list(arch["obs_shape"]):
        raise UserError(
            f"dataset images are {data.image_shape} but the policy expects {tuple(arch['obs_shape'])}; use data from "
            "the policy's task"
        )
    if data.discrete != policy.discrete or (not data.discrete and data.labels.shape[1] != arch["n_outputs"]):
        kind = "int64 class labels" if policy.discrete else f"float32 labels of width {arch['n_outputs']}"
        raise UserError(
            f"dataset labels are {data.labels.dtype} {data.labels.shape[1:]} but the policy needs {kind}; use data "
            "from the policy's task"
        )


def fit_bc(
    policy: Policy,
    data: Dataset | Aggregate,
    config: BCConfig,
    *,
    progress: bool = False,
    cache: FeatureCache | None = None,
    on_epoch: Callable[[int], None] | None = None,
    called: str = "the BC fit",
) -> dict[str, Any]:
    """Fit ``policy`` in place to ``data`` with Adam: cross-entropy (discrete) or MSE (continuous).

    Each epoch shuffles the data with the fit's seeded generator and takes one Adam step per batch
    (:class:`ReferenceEpoch`, BC as a textbook writes it). Two fast paths take the same steps
    where they serve: a head-only fit of a linear head runs each epoch in one compiled call
    (:class:`~metadagger.imitation.head_adam.LinearHeadAdam`, bit-equal to the reference), and
    a whole-policy fit with ``batch_shards`` above 1 splits each batch's gradient over threads
    (:class:`ShardedEpoch`, the same gradient summed in another order). On a run's GPU
    (:func:`~metadagger.utils.device.compute_device`) every fit but a linear head's takes the
    reference steps there (:class:`DeviceEpoch`).

    Args:
        policy: the policy to train (its network is updated in place).
        data: observations and expert labels (an :class:`Aggregate`'s images are concatenated only
            for a whole-policy fit).
        config: optimiser settings; ``config.head_only`` fits layer n on cached trunk features;
            ``config.augment_shift`` shifts the images of whole-policy fits at random.
        progress: show a progress bar over epochs.
        cache: features to reuse across calls (head-only fits only); a fresh one if None.
        on_epoch: called with the epoch's number (1, 2, ...) after each epoch, the policy holding
            that epoch's weights (an :class:`~metadagger.imitation.selection.EpochSelector`, say).
        called: how an error names this fit.

    Returns:
        ``{"loss": [mean training loss per epoch], "samples": N, "seconds": wall time}``.

    Raises:
        DivergedError: an epoch's mean loss, or a weight at the end, is not finite (the policy is
            then left as it is: its caller must not keep it).
    """
    check_data(policy, data)
    started = time.perf_counter()
    inputs, model = _inputs_and_model(policy, data, config, cache)
    targets = torch.from_numpy(data.labels)
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise UserError("the policy has no trainable parameters left to fit; do not freeze the head")
    generator = torch.Generator().manual_seed(config.seed)
    n, losses = len(data), []
    with _epochs(model, params, inputs, targets, config, policy.discrete, generator) as run_epoch:
        bar = progress_bar(range(config.epochs), desc="bc", enabled=progress, leave=False)
        for epoch in bar:
            order = torch.randperm(n, generator=generator)
            batch_losses = run_epoch(epoch, order)
            sizes = [min(config.batch_size, n - start) for start in range(0, n, config.batch_size)]
            losses.append(sum(loss * size for loss, size in zip(batch_losses, sizes, strict=True)) / n)
            check_finite_loss(
                losses[-1],
                called=called,
                epoch=epoch + 1,
                epochs=config.epochs,
                fix=f"lower its learning rate (now {config.lr:g}) or check its data",
            )
            bar.set_postfix(loss=f"{losses[-1]:.4f}")
            if on_epoch is not None:
                run_epoch.write_back()
                on_epoch(epoch + 1)
        run_epoch.write_back()
    if not bool(torch.isfinite(parameters_to_vector(params)).all()):
        raise DivergedError(
            f"{called} diverged: its weights are not finite after {config.epochs} epochs; "
            f"lower its learning rate (now {config.lr:g}) or check its data"
        )
    return {"loss": losses, "samples": n, "seconds": time.perf_counter() - started}


def head_fit(
    policy: Policy, data: Dataset | Aggregate, config: BCConfig, cache: FeatureCache, *, called: str
) -> HeadFit:
    """The head-only fit :func:`fit_bc` would run (its data, its seeded batch orders, its Adam), as a
    request for :func:`~metadagger.imitation.head_fits.fit_heads`, which runs many fits batched."""
    check_data(policy, data)
    if not (config.head_only and LinearHeadAdam.supports(policy.net.head)):
        raise UserError(f"{called} is not a head-only fit of a linear head; batched fits need head_only=true")
    _check_cache(cache, policy)
    generator = torch.Generator().manual_seed(config.seed)
    return HeadFit(
        head=policy.head_vector().detach().clone(),
        features=cache.features_of(data),
        targets=torch.from_numpy(data.labels),
        orders=torch.stack([torch.randperm(len(data), generator=generator) for _ in range(config.epochs)]),
        lr=config.lr,
        weight_decay=config.weight_decay,
        batch_size=config.batch_size,
        called=called,
    )


def _check_cache(cache: FeatureCache, policy: Policy) -> None:
    if cache.policy.net.trunk is not policy.net.trunk:
        raise UserError("the FeatureCache was built for another trunk; build one with FeatureCache(policy)")


def _inputs_and_model(
    policy: Policy, data: Dataset | Aggregate, config: BCConfig, cache: FeatureCache | None
) -> tuple[torch.Tensor | ImageRows, torch.nn.Module]:
    """What a fit trains on and what it trains: cached trunk features and the head, or images (in
    their parts: :class:`~metadagger.imitation.image_rows.ImageRows`) and the network."""
    if config.head_only:
        cache = cache if cache is not None else FeatureCache(policy)
        _check_cache(cache, policy)
        return cache.features_of(data), policy.net.head
    if cache is not None:
        raise UserError("a FeatureCache only applies to head-only fits; set BCConfig(head_only=True) or drop cache=")
    return ImageRows(data), policy.net


class ReferenceEpoch:
    """One epoch of BC as a textbook writes it, the reference of every fast path: for each batch
    of the epoch's order, the mean loss, its gradient by autograd, one Adam step."""

    def __init__(
        self,
        model: torch.nn.Module,
        params: list[torch.nn.Parameter],
        inputs: torch.Tensor | ImageRows,
        targets: torch.Tensor,
        config: BCConfig,
        discrete: bool,
        generator: torch.Generator,
    ) -> None:
        self.model, self.inputs, self.targets, self.config, self.generator = model, inputs, targets, config, generator
        self.loss_fn = F.cross_entropy if discrete else F.mse_loss
        self.optimizer = adam(params, lr=config.lr, weight_decay=config.weight_decay)

    def __call__(self, epoch: int, order: torch.Tensor) -> list[float]:
        """The epoch's batches in ``order``; each batch's loss before its step."""
        for group in self.optimizer.param_groups:
            group["lr"] = self.config.lr_at(epoch)
        losses = []
        for batch in order.split(self.config.batch_size):
            x = self.inputs[batch]
            if self.config.augment_shift:
                x = random_shift(x, self.config.augment_shift, self.generator)
            losses.append(self.step(x, self.targets[batch]))
        return losses

    def step(self, x: torch.Tensor, y: torch.Tensor) -> float:
        """One Adam step on the batch's mean loss; the loss."""
        loss = self.loss_fn(self.model(x), y)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.item()

    def write_back(self) -> None:
        """The model holds the weights already."""


class ShardedEpoch(ReferenceEpoch):
    """The reference epoch with each batch's gradient computed in ``config.batch_shards`` contiguous
    parts in ``pool``'s threads and added in shard order, then divided by the batch's count: the
    mean loss's gradient summed another way (equal to the reference's up to rounding).

    Each shard differentiates with ``torch.autograd.grad``, which returns its gradients rather
    than accumulating them into the shared parameters, so the threads never write the same tensor.
    """

    def __init__(self, *args: Any, pool: ThreadPoolExecutor, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.pool = pool
        self.params = [p for group in self.optimizer.param_groups for p in group["params"]]

    def _shard(self, xy: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
        loss = self.loss_fn(self.model(xy[0]), xy[1], reduction="sum")
        return loss.detach(), torch.autograd.grad(loss, self.params)

    def step(self, x: torch.Tensor, y: torch.Tensor) -> float:
        shards = self.config.batch_shards
        parts = [(xs, ys) for xs, ys in zip(x.tensor_split(shards), y.tensor_split(shards)) if len(xs)]
        results = list(self.pool.map(self._shard, parts))
        count = len(y) if self.loss_fn is F.cross_entropy else y.numel()
        loss = results[0][0]
        for part_loss, _ in results[1:]:
            loss = loss + part_loss
        for i, param in enumerate(self.params):
            grad = results[0][1][i]
            for _, grads in results[1:]:
                grad = grad + grads[i]
            param.grad = grad / count
        self.optimizer.step()
        return (loss / count).item()


class HeadAdamEpoch:
    """The reference epoch of a head-only fit of a linear head, in one compiled call
    (:class:`~metadagger.imitation.head_adam.LinearHeadAdam`, bit-equal to it)."""

    def __init__(
        self, head: torch.nn.Linear, features: torch.Tensor, targets: torch.Tensor, config: BCConfig, discrete: bool
    ) -> None:
        self.adam = LinearHeadAdam(head, lr=config.lr, weight_decay=config.weight_decay, discrete=discrete)
        self.features, self.targets, self.batch_size = features, targets, config.batch_size

    def __call__(self, epoch: int, order: torch.Tensor) -> list[float]:
        return self.adam.steps(self.features, self.targets, order, self.batch_size).tolist()

    def write_back(self) -> None:
        """Copy the trained weights into the head."""
        self.adam.write_back()


class DeviceEpoch:
    """The reference epoch on a GPU (the run's compute device), built on the network and the data
    there: the network back on the CPU whenever it is read (:meth:`write_back`)."""

    def __init__(self, reference: ReferenceEpoch, device: torch.device) -> None:
        self.reference, self.model, self.device = reference, reference.model, device

    def __call__(self, epoch: int, order: torch.Tensor) -> list[float]:
        self.model.to(self.device)
        return self.reference(epoch, order)

    def write_back(self) -> None:
        """Bring the network back to the CPU (its optimiser's state stays on the device)."""
        self.model.to("cpu")


@contextmanager
def _epochs(
    model: torch.nn.Module,
    params: list[torch.nn.Parameter],
    inputs: torch.Tensor | ImageRows,
    targets: torch.Tensor,
    config: BCConfig,
    discrete: bool,
    generator: torch.Generator,
) -> Iterator[ReferenceEpoch | ShardedEpoch | HeadAdamEpoch | DeviceEpoch]:
    """The epoch a fit runs: a fast path where one serves it, the reference on the run's GPU where
    it has one, else the reference."""
    device = compute_device()
    if config.head_only and LinearHeadAdam.supports(model):
        yield HeadAdamEpoch(model, inputs, targets, config, discrete)  # type: ignore[arg-type]
    elif device.type != "cpu":
        model.to(device)
        reference = ReferenceEpoch(model, params, inputs.to(device), targets.to(device), config, discrete, generator)
        epoch = DeviceEpoch(reference, device)
        try:
            yield epoch
        finally:
            epoch.write_back()
    elif config.batch_shards > 1:
        # a new thread starts with OpenMP's default thread count, not the caller's torch.set_num_threads
        with ThreadPoolExecutor(
            config.batch_shards,
            thread_name_prefix="bc-shard",
            initializer=torch.set_num_threads,
            initargs=(torch.get_num_threads(),),
        ) as pool:
            yield ShardedEpoch(model, params, inputs, targets, config, discrete, generator, pool=pool)
    else:
        yield ReferenceEpoch(model, params, inputs, targets, config, discrete, generator)


def fit_or_resume(
    policy: Policy,
    data: Dataset | Aggregate,
    config: BCConfig,
    checkpoint: str | Path | None,
    *,
    cache: FeatureCache | None = None,
    progress: bool = False,
    selector: EpochSelector | None = None,
    called: str = "the BC fit",
) -> list[float] | None:
    """:func:`fit_bc`, then save the policy at ``checkpoint``; if that checkpoint already exists
    (a killed run being resumed) load its weights instead of fitting. With a ``selector`` the
    policy saved (and left in ``policy``) is the epoch it chose.

    Returns:
        The mean training loss of every epoch, or None when the weights were loaded.
    """
    if checkpoint is not None and Path(checkpoint).is_file():
        policy.net.load_state_dict(load_policy(checkpoint).net.state_dict())
        return None
    losses = fit_bc(policy, data, config, progress=progress, cache=cache, on_epoch=selector, called=called)["loss"]
    if selector is not None:
        selector.restore()
    if checkpoint is not None:
        policy.save(checkpoint)
    return losses
