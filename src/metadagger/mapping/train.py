"""Training the mappers (paper section 3.3, Table 8), with curves on disk and resume.

:func:`train_mapper` fits the autoencoder(s) first, then the latent regression h on the frozen
encoders' codes (SAM, TAM), or the single MLP (DM): Adam, MSE in standardised space, manual
batching from one seeded generator. It writes ``curves.csv`` (drawn as paper Fig. 8 by
:mod:`metadagger.evaluation.curves`) and, last, ``mapper.safetensors``; an existing mapper file
means the work is done and is loaded.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import io
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from metadagger.errors import DivergedError, UserError, check_finite_loss
from metadagger.mapping.config import MapperConfig
from metadagger.mapping.mappers import ARCH_FIELDS, Mapper, Standardizer, build_networks, load_mapper
from metadagger.mapping.registry import Route, get_kind
from metadagger.metal_dagger.store import PairSplit
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import CURVES_FILE, MAPPER_FILE
from metadagger.runfolder.stamps import data_fingerprint, describe_changes, stamp_of
from metadagger.utils.device import compute_device
from metadagger.utils.executors import default_workers, make_executor
from metadagger.utils.io import write_text
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.optim import adam
from metadagger.utils.progress import note, progress_bar

__all__ = [
    "CURVE_COLUMNS",
    "MapperJob",
    "evaluate_mapping",
    "fit_mapper",
    "fit_mapper_job",
    "train_mapper",
    "train_mappers",
]

CURVE_COLUMNS = ("model", "epoch", "train_loss", "val_loss", "train_mse_weights", "val_mse_weights")
"""``curves.csv`` columns. ``*_loss``: the model's own MSE (standardised weights, or latent codes
for h), train averaged over the epoch's batches. ``*_mse_weights``: MSE of the whole mapping f in
original weight units after the epoch, for the last stage only, so kinds compare directly."""


def train_mapper(
    split: PairSplit,
    config: MapperConfig,
    out_dir: str | Path,
    *,
    pistar_head: np.ndarray | torch.Tensor | None = None,
    rebuild: bool = False,
    progress: bool = True,
) -> Mapper:
    """Train (or, if ``out_dir/mapper.safetensors`` exists and was made from the same config and
    data, load) a mapper of ``config.kind``.

    Args:
        split: training and validation pairs; only the training rows fit weights and standardisers.
        config: architecture and optimiser settings.
        out_dir: receives ``mapper.safetensors`` and ``curves.csv``.
        pistar_head: pi*'s head vector, required by the ``pistar-head`` control.
        rebuild: retrain a mapper in ``out_dir`` that was made from another config or other pairs.
        progress: show a progress bar per training stage.

    Returns:
        The mapper, in eval mode (the same one ``load_mapper(out_dir / MAPPER_FILE)`` gives).

    Raises:
        UserError: too few training pairs, a missing or mis-sized ``pistar_head``, or (without
            ``rebuild``) an existing mapper in ``out_dir`` made from another config or other pairs.
    """
    job = MapperJob(split=split, config=config, out_dir=Path(out_dir), pistar_head=pistar_head)
    return train_mappers([job], rebuild=rebuild, options=StageOptions(workers=1, progress=progress))[0]


@dataclass(frozen=True)
class MapperJob:
    """One mapper to train, as :func:`train_mappers` hands it to a worker (picklable)."""

    split: PairSplit
    config: MapperConfig
    out_dir: Path
    """Receives ``mapper.safetensors`` and ``curves.csv`` (written by the driver)."""
    pistar_head: np.ndarray | torch.Tensor | None = None
    """pi*'s head vector, required by the ``pistar-head`` control."""
    name: str = ""
    """How progress and errors name the job (default: its kind)."""

    @property
    def label(self) -> str:
        """The job's name, or its kind."""
        return self.name or self.config.kind

    def __repr__(self) -> str:  # what an error from a worker names: not the pairs' tensors
        return f"mapper {self.label} ({len(self.split.train_seeds)} training pairs, {self.out_dir})"


def train_mappers(
    jobs: Sequence[MapperJob], *, rebuild: bool = False, options: StageOptions = StageOptions()
) -> list[Mapper]:
    """:func:`train_mapper` for every job, the ones to train in parallel, one job per worker.

    Each fit is a function of its job alone (one torch thread, its own seeded generators), so a
    mapper is the same to the bit whichever worker, or the driver, fits it. The driver loads the
    jobs whose mapper is up to date, checks every stale one against ``rebuild`` before any work,
    and writes each new mapper as its fit arrives, so a killed stage keeps the finished ones.

    Returns:
        The mappers, in the order of ``jobs``.
    """
    mappers = [_up_to_date(job, rebuild=rebuild) for job in jobs]
    # longest fits first, so no worker starts a long one when the others are about to finish
    pending = sorted((i for i, mapper in enumerate(mappers) if mapper is None), key=lambda i: -_fit_cost(jobs[i]))
    if len(pending) == 1 or (options.executor == "local" and options.workers == 1):
        for i in pending:  # in the driver, with the fit's own progress bars
            mappers[i] = _save(
                jobs[i],
                *fit_mapper(jobs[i].split, jobs[i].config, pistar_head=jobs[i].pistar_head, progress=options.progress),
            )
    elif pending:
        workers = (
            min(options.workers or default_workers(), len(pending)) if options.executor == "local" else options.workers
        )
        started = time.monotonic()
        number = {jobs[i].out_dir: i for i in pending}
        with make_executor(options.executor, workers=workers, address=options.address) as pool:
            for done, (out_dir, mapper, rows) in enumerate(
                pool.imap_unordered(fit_mapper_job, [jobs[i] for i in pending]), 1
            ):
                i = number[out_dir]
                mappers[i] = _save(jobs[i], mapper, rows)
                note(
                    f"mappers: {jobs[i].label} trained ({done}/{len(pending)} in {time.monotonic() - started:.0f}s)",
                    enabled=options.progress,
                )
    return [mapper for mapper in mappers if mapper is not None]


def fit_mapper_job(job: MapperJob) -> tuple[Path, Mapper, list[dict[str, Any]]]:
    """A worker's part of :func:`train_mappers`: the job's folder, its mapper and curve rows (in memory)."""
    mapper, rows = fit_mapper(job.split, job.config, pistar_head=job.pistar_head, progress=False)
    return job.out_dir, mapper, rows


def _fit_cost(job: MapperJob) -> int:
    """Adam epochs times training rows, roughly proportional to the job's fit time: 0 for closed
    forms and controls; the autoencoder stage (SAM's on twice the rows, TAM's two networks)
    counted twice."""
    kind = get_kind(job.config.kind)
    if kind.route is None or kind.closed_form is not None:
        return 0
    epochs = job.config.epochs + (2 * job.config.ae_epochs if kind.route.encoder is not None else 0)
    return epochs * len(job.split.train_seeds)


def _up_to_date(job: MapperJob, *, rebuild: bool) -> Mapper | None:
    """The job's existing mapper if it was made from the job's inputs; None if it must be trained.

    Raises:
        UserError: without ``rebuild``, an existing mapper made from other inputs.
    """
    path = job.out_dir / MAPPER_FILE
    if not path.exists():
        return None
    existing = load_mapper(path)
    changes = describe_changes(existing.stamp, mapper_stamp(job.split, job.config, job.pistar_head))
    if not changes:
        return existing
    if not rebuild:
        raise UserError(
            f"{path} holds a mapper made from other inputs ({'; '.join(changes)}); "
            "pass --rebuild to retrain it, or run `metadagger reproduce`"
        )
    return None


def _save(job: MapperJob, mapper: Mapper, rows: list[dict[str, Any]]) -> Mapper:
    """Stamp and write a fitted mapper: its curves, then (last: its presence means the work is
    complete) ``mapper.safetensors``."""
    mapper.stamp = mapper_stamp(job.split, job.config, job.pistar_head)
    _write_curves(job.out_dir / CURVES_FILE, rows)
    mapper.save(job.out_dir / MAPPER_FILE)
    return mapper


def fit_mapper(
    split: PairSplit,
    config: MapperConfig,
    *,
    pistar_head: np.ndarray | torch.Tensor | None = None,
    progress: bool = True,
) -> tuple[Mapper, list[dict[str, Any]]]:
    """Train a mapper of ``config.kind`` in memory, writing nothing: the work of
    :func:`train_mapper`, and of each trial of :mod:`metadagger.mapping.tune`.

    Args:
        split, config, pistar_head, progress: as for :func:`train_mapper`.

    Returns:
        The mapper in eval mode (without a stamp) and its curve rows (:data:`CURVE_COLUMNS`).

    Raises:
        UserError: too few training pairs, or a missing or mis-sized ``pistar_head``.
    """
    if get_kind(config.kind).learned and len(split.train_seeds) < 2:
        raise UserError(
            f"a {config.kind} mapper needs at least 2 training pairs, got {len(split.train_seeds)}; collect more "
            "seeds or lower val_fraction"
        )
    config_data = json.loads(json.dumps(dataclasses.asdict(config)))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)  # Dropout draws from torch's global generator
        return _train(split, config, config_data, pistar_head, progress)


def mapper_stamp(
    split: PairSplit, config: MapperConfig, pistar_head: np.ndarray | torch.Tensor | None = None
) -> dict[str, Any]:
    """What a mapper is made from: its config and a fingerprint of its training data (the split's
    seeds and tensors, and pi*'s head for the ``pistar-head`` control)."""
    parts: list[Any] = [list(split.train_seeds), list(split.val_seeds)]
    parts += [
        t.contiguous().numpy().tobytes() for t in (split.w_bc_train, split.w_da_train, split.w_bc_val, split.w_da_val)
    ]
    if get_kind(config.kind).context and split.context_train is not None:
        parts += [t.contiguous().numpy().tobytes() for t in (split.context_train, split.context_val)]
    if pistar_head is not None and config.kind == "pistar-head":
        parts.append(torch.as_tensor(pistar_head, dtype=torch.float32).numpy().tobytes())
    return {**kernel_stamp(), "config": stamp_of(config), "pairs_fingerprint": data_fingerprint(*parts)}


def _train(
    split: PairSplit, config: MapperConfig, config_data: dict[str, Any], pistar_head: Any, progress: bool
) -> tuple[Mapper, list[dict[str, Any]]]:
    bc_tr, da_tr, bc_va, da_va = (
        t.to(torch.float32) for t in (split.w_bc_train, split.w_da_train, split.w_bc_val, split.w_da_val)
    )
    dim = bc_tr.shape[1]
    spec = get_kind(config.kind)
    if spec.context and split.context_train is None:
        raise UserError(
            f"the {config.kind} mapper needs each pair's context, but these pairs were stored without one; "
            "collect them again with `metadagger pairs --rebuild` (or `metadagger reproduce --rebuild`)"
        )
    ctx_tr, ctx_va = (split.context_train, split.context_val) if spec.context else (None, None)

    def weight_mse(mapper: Mapper) -> tuple[float, float]:
        return _mse(mapper.map_tensor(bc_tr, ctx_tr), da_tr), _mse(mapper.map_tensor(bc_va, ctx_va), da_va)

    if not spec.learned:
        head = None if pistar_head is None else torch.as_tensor(pistar_head, dtype=torch.float32)
        mapper = Mapper.control(config.kind, w_da_train=da_tr, pistar_head=head, config=config_data)
        if mapper.dim != dim:
            raise UserError(
                f"pistar_head has length {mapper.dim}, expected {dim}: the head of the policy the pairs came from"
            )
        train_w, val_w = weight_mse(mapper)
        return mapper, [_row(config.kind, 0, math.nan, math.nan, train_w, val_w)]

    generator = torch.Generator().manual_seed(config.seed)
    context_dim = 0 if ctx_tr is None else ctx_tr.shape[1]
    networks = build_networks(
        config.kind, dim, context_dim=context_dim, **{f: getattr(config, f) for f in ARCH_FIELDS}, generator=generator
    )
    route = spec.route
    scalers = (
        {"all": Standardizer.fit(torch.cat([bc_tr, da_tr]))}
        if route.in_scaler == "all"
        else {"bc": Standardizer.fit(bc_tr), "da": Standardizer.fit(da_tr)}
    )
    if ctx_tr is not None:
        scalers["context"] = Standardizer.fit(ctx_tr)
    mapper = Mapper(
        kind=config.kind, dim=dim, networks=networks, scalers=scalers, config=config_data, context_dim=context_dim
    )
    x_tr, x_va = scalers[route.in_scaler].transform(bc_tr), scalers[route.in_scaler].transform(bc_va)
    if ctx_tr is not None:  # the core reads [w_BC, context], both standardised (Mapper.map_tensor)
        x_tr = torch.cat([x_tr, scalers["context"].transform(ctx_tr)], dim=1)
        x_va = torch.cat([x_va, scalers["context"].transform(ctx_va)], dim=1)
    y_tr, y_va = scalers[route.out_scaler].transform(da_tr), scalers[route.out_scaler].transform(da_va)
    fit = dict(
        lr=config.lr,
        batch_size=config.batch_size,
        generator=generator,
        progress=progress,
        owner=f"the {config.kind} mapper",
    )
    rows: list[dict[str, Any]] = []
    if spec.closed_form is not None:
        mapper.config["fit"] = spec.closed_form(networks[route.core], x_tr, y_tr)
        _check_weights(
            networks[route.core],
            f"the {config.kind} mapper's closed-form fit",
            "check the pairs (metadagger pairs --rebuild)",
        )
        networks[route.core].eval()
        with torch.no_grad():
            losses = _mse(networks[route.core](x_tr), y_tr), _mse(networks[route.core](x_va), y_va)
        return mapper, [_row(route.core, 0, *losses, *weight_mse(mapper))]
    data = (x_tr, y_tr, x_va, y_va)
    if route.encoder is not None:
        data = _fit_autoencoders(
            networks, route, data, rows, epochs=config.ae_epochs, weight_decay=config.ae_weight_decay, **fit
        )
    after_epoch = functools.partial(weight_mse, mapper)
    rows += _fit(
        networks[route.core],
        route.core,
        *data,
        epochs=config.epochs,
        weight_decay=config.weight_decay,
        after_epoch=after_epoch,
        **fit,
    )
    return mapper, rows


def _fit_autoencoders(
    networks: dict[str, nn.Module], route: Route, data: tuple[torch.Tensor, ...], rows: list[dict[str, Any]], **fit: Any
) -> tuple[torch.Tensor, ...]:
    """Fit the route's autoencoder(s), append their curves to ``rows``, return h's latent data."""
    x_tr, y_tr, x_va, y_va = data
    # Each autoencoder learns every standardised vector it will encode or decode: sigma_ALL both sets.
    if route.encoder == route.decoder:
        ae_data = {route.encoder: (torch.cat([x_tr, y_tr]), torch.cat([x_va, y_va]))}
    else:
        ae_data = {route.encoder: (x_tr, x_va), route.decoder: (y_tr, y_va)}
    for name, (d_tr, d_va) in ae_data.items():
        rows += _fit(networks[name], name, d_tr, d_tr, d_va, d_va, **fit)
    # h learns on the codes of the frozen (eval-mode) encoders, computed once.
    encoder, target_encoder = networks[route.encoder], networks[route.decoder]
    encoder.eval()
    target_encoder.eval()
    with torch.no_grad():
        return encoder.encode(x_tr), target_encoder.encode(y_tr), encoder.encode(x_va), target_encoder.encode(y_va)


def _fit(
    net: nn.Module,
    name: str,
    x_tr: torch.Tensor,
    y_tr: torch.Tensor,
    x_va: torch.Tensor,
    y_va: torch.Tensor,
    *,
    epochs: int,
    lr: float,
    weight_decay: float,
    batch_size: int,
    generator: torch.Generator,
    progress: bool,
    owner: str,
    after_epoch: Callable[[], tuple[float, float]] | None = None,
) -> list[dict[str, Any]]:
    """Adam on the MSE of ``net(x)`` against ``y``; one curve row per epoch. A loss or weight that
    becomes non-finite stops it with a :class:`DivergedError` naming ``owner``, ``name`` and the epoch.
    The steps run on the run's compute device (:func:`~metadagger.utils.device.compute_device`);
    each epoch's evaluation, and the network after the fit, on the CPU."""
    device = compute_device()
    x_steps, y_steps = x_tr.to(device), y_tr.to(device)
    optimizer = adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    rows = []
    bar = progress_bar(range(1, epochs + 1), desc=f"mapping/{name}", enabled=progress, leave=False)
    for epoch in bar:
        net.to(device).train()
        total = torch.zeros((), device=device)
        for idx in _batches(torch.randperm(len(x_tr), generator=generator), batch_size):
            loss = F.mse_loss(net(x_steps[idx]), y_steps[idx])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += loss.detach() * len(idx)
        net.to("cpu").eval()
        with torch.no_grad():
            val_loss = _mse(net(x_va), y_va) if len(x_va) else math.nan
        weights = after_epoch() if after_epoch else (math.nan, math.nan)
        rows.append(_row(name, epoch, float(total) / len(x_tr), val_loss, *weights))
        check_finite_loss(
            rows[-1]["train_loss"],
            called=f"{owner}'s network {name}",
            epoch=epoch,
            epochs=epochs,
            fix=f"lower its learning rate (now {lr:g})",
        )
        bar.set_postfix(
            train=f"{rows[-1]['train_loss']:.4g}", val=f"{val_loss:.4g}", refresh=False
        )  # tqdm throttles redraws
    _check_weights(net, f"{owner}'s network {name}", f"lower its learning rate (now {lr:g})")
    return rows


def _check_weights(net: nn.Module, called: str, fix: str) -> None:
    """Raise :class:`DivergedError` if a weight of ``net`` is not finite."""
    if not all(bool(torch.isfinite(p).all()) for p in net.parameters()):
        raise DivergedError(f"{called} diverged: its weights are not finite; {fix}")


def _batches(order: torch.Tensor, batch_size: int) -> list[torch.Tensor]:
    chunks = list(order.split(batch_size))
    # BatchNorm cannot normalise a batch of one in training mode: fold a lone last row into the batch before.
    if len(chunks) > 1 and len(chunks[-1]) == 1:
        chunks[-2:] = [torch.cat(chunks[-2:])]
    return chunks


def _mse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(F.mse_loss(a, b)) if len(a) else math.nan


def _row(model: str, epoch: int, train_loss: float, val_loss: float, train_w: float, val_w: float) -> dict[str, Any]:
    return dict(zip(CURVE_COLUMNS, (model, epoch, train_loss, val_loss, train_w, val_w)))


def _write_curves(path: Path, rows: list[dict[str, Any]]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CURVE_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(
            {
                k: ("" if isinstance(v, float) and math.isnan(v) else format(v, ".9g") if isinstance(v, float) else v)
                for k, v in row.items()
            }
        )
    write_text(path, buffer.getvalue())


def evaluate_mapping(
    mapper: Mapper,
    w_bc: np.ndarray | torch.Tensor,
    w_da: np.ndarray | torch.Tensor,
    *,
    mean_da: np.ndarray | torch.Tensor | None = None,
    context: np.ndarray | torch.Tensor | None = None,
) -> dict[str, float]:
    """How close ``mapper(w_bc)`` comes to ``w_da`` on rows ``[N, d]``, in original weight units.

    Args:
        mapper: the mapper to evaluate.
        w_bc: heads after BC (inputs).
        w_da: heads after DAgger (targets), same shape.
        context: the seeds' contexts ``[N, k]``, for a mapper that reads them.
        mean_da: the mean-DA baseline's vector (the training mean); None uses the mean of ``w_da``,
            which makes ``relative_mse`` one minus the coefficient of determination.

    Returns:
        ``mse``; ``baseline_mse`` of always predicting ``mean_da``; ``relative_mse`` = their ratio
        (below 1: better than the baseline); ``cosine``: mean cosine similarity of prediction and
        target rows; ``cosine_update``: the same for the updates ``pred - w_bc`` and ``w_da - w_bc``;
        ``n``: rows.
    """
    bc = torch.as_tensor(np.asarray(w_bc, dtype=np.float32))
    da = torch.as_tensor(np.asarray(w_da, dtype=np.float32))
    if bc.ndim != 2 or bc.shape != da.shape or len(bc) == 0:
        raise UserError(
            f"w_bc and w_da must be non-empty [N, d] of one shape, got {tuple(bc.shape)} and {tuple(da.shape)}"
        )
    pred = torch.from_numpy(mapper.map_batch(bc, context))
    ref = da.mean(dim=0) if mean_da is None else torch.as_tensor(np.asarray(mean_da, dtype=np.float32))
    mse, baseline = _mse(pred, da), _mse(ref.expand_as(da), da)
    return {
        "mse": mse,
        "baseline_mse": baseline,
        "relative_mse": mse / baseline if baseline > 0 else math.nan,
        "cosine": float(F.cosine_similarity(pred, da, dim=1).mean()),
        "cosine_update": float(F.cosine_similarity(pred - bc, da - bc, dim=1).mean()),
        "n": len(bc),
    }
