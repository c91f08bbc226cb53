"""TensorBoard scalars of a run, written from its artifacts on disk (``log: tensorboard``).

Each namespace is one TensorBoard run, a folder ``RUN/tb/<namespace>/`` built from one stage's
files alone, like the report; every tag starts with its namespace:

- ``pistar``: pi*'s fits, DAgger rounds and final success (``pistar/metrics.json``);
- ``pairs``: every seed's BC and DAgger outcomes and the outcome counts (``pairs/``);
- ``mapper/<kind>``: the learning curves of every model of a mapper, autoencoders included
  (``mappers/<kind>/curves.csv``);
- ``eval/mdm``, ``eval/oneshot``, ``eval/mdi``: one scalar per (method, seed) and each method's
  means (``eval/*.csv``);
- ``benchmark``: the same for ``benchmark/queries.csv``, and success against mean expert queries
  (``benchmark/summary.json``).

A stage rewrites its namespaces when it finishes: the event files are written into a temporary
folder that then replaces the namespace's folder, so a resumed or re-run stage never adds points
to the earlier ones. tensorboard is imported here only, on first use (the ``tensorboard`` extra).
docs/tensorboard.md lists every tag.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from metadagger.errors import UserError
from metadagger.evaluation.rows import CURVE_COLUMNS, read_csv
from metadagger.metal_dagger.store import OUTCOME_KEYS, PairStore
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import atomic_folder, read_json

Scalar = tuple[str, Any, int]
"""One point: its tag below the namespace, its value, its step. A value that is not a number (an
empty CSV cell, None) is left out when written; booleans are written as 0 and 1."""

INSTALL = 'pip install -c constraints.txt -e ".[tensorboard]"'
"""How to install the optional dependency."""

_ROW_KEYS = ("method", "setting", "seed", "demo_fraction")
"""Columns of an evaluation table that name a row rather than measure it."""


def require_tensorboard() -> type:
    """torch's ``SummaryWriter`` (importing tensorboard).

    Raises:
        UserError: tensorboard is not installed; the line names the command that installs it.
    """
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError as exc:
        raise UserError(
            f"log: tensorboard needs the tensorboard package ({exc}); install it with `{INSTALL}` or set log: none"
        ) from None
    return SummaryWriter


def pistar_scalars(layout: RunLayout) -> list[Scalar]:
    """pi*'s training and outcome.

    ``loss`` per epoch of its fits, one after another (fit k, 0 being BC, covers steps
    ``k*E+1 .. (k+1)*E`` for E epochs per fit; a fit resumed from its checkpoint, or made before
    pi*'s metrics recorded epoch losses, has none);
    ``dagger/<key>`` of every DAgger round's record at step = round; ``own_seeds/<key>``,
    ``unseen_seeds/<key>`` and ``expert_queries`` of the final pi* at step = its rounds;
    ``select/successes`` at step = epoch for each check of ``pistar.select_seeds``, and
    ``select/chosen_epoch`` at step 0.
    """
    metrics = read_json(layout.pistar_metrics, "pi*'s metrics")
    rounds = metrics["rounds"]
    fits = [metrics.get("bc_epoch_losses"), *(r.get("dagger/epoch_losses") for r in rounds)]
    out = [
        ("loss", loss, k * len(losses) + epoch)
        for k, losses in enumerate(fits)
        if losses
        for epoch, loss in enumerate(losses, 1)
    ]
    for record in rounds:
        out += [(key, value, record["dagger/round"]) for key, value in record.items() if key != "dagger/round"]
    out += [
        (f"{name}/{key}", value, len(rounds))
        for name in ("own_seeds", "unseen_seeds")
        for key, value in metrics[name].items()
    ]
    choice = metrics.get("bc_selection")
    if choice:
        out += [("select/successes", check["successes"], check["epoch"]) for check in choice["history"]]
        out.append(("select/chosen_epoch", choice["epoch"], 0))
    return out + [("expert_queries", metrics["expert_queries"], len(rounds))]


def pairs_scalars(layout: RunLayout, seeds: Iterable[int]) -> list[Scalar]:
    """The pairs of ``seeds``: ``bc/<key>`` and ``da/<key>`` (success, reward, steps,
    expert_queries) and ``kept`` at step = seed; ``summary/...``: every number of
    ``pairs/summary.json`` (outcome counts and shares, kept pairs, mean rewards) at step 0."""
    wanted = set(seeds)
    out = []
    for record in (r for r in PairStore(layout.pairs_dir).records() if r["seed"] in wanted):
        out += [
            (f"{outcome}/{key}", record[outcome][key], record["seed"])
            for outcome in ("bc", "da")
            for key in OUTCOME_KEYS
        ]
        out.append(("kept", record["kept"], record["seed"]))
    return out + [
        (f"summary/{tag}", value, 0) for tag, value in _leaves(read_json(layout.pairs_summary, "the pairs summary"))
    ]


def mapper_scalars(layout: RunLayout, kind: str) -> list[Scalar]:
    """Mapper ``kind``'s learning curves at step = epoch: ``<model>/train_loss`` and
    ``<model>/val_loss`` of every network it trains (autoencoders, then h; or DM's MLP) and
    ``train_mse_weights`` / ``val_mse_weights`` of the whole mapping (a control's at step 0)."""
    out = []
    for row in read_csv(layout.mapper_curves(kind), columns=CURVE_COLUMNS):
        out += [(f"{row['model']}/{key}", row[key], row["epoch"]) for key in ("train_loss", "val_loss")]
        out += [(key, row[key], row["epoch"]) for key in ("train_mse_weights", "val_mse_weights")]
    return out


def table_scalars(path: Path) -> list[Scalar]:
    """An evaluation table (``eval/*.csv``, ``benchmark/queries.csv``): every measured column of a
    row as ``<method>/<column>`` at step = seed (``<method>@<setting>/...`` where the table has
    settings; ``...@demo<share>`` for rows from a share of the demonstration), and its mean over
    the seeds where present as ``<method>/mean/<column>`` at step 0 (``mean/success``: the success
    rate)."""
    out = []
    values: dict[str, list[float]] = {}
    for row in read_csv(path):
        group = row["method"] if row.get("setting", "") == "" else f"{row['method']}@{row['setting']}"
        group += _share_suffix(row.get("demo_fraction"))
        for key, value in row.items():
            number = _number(value)
            if key not in _ROW_KEYS and number is not None:
                out.append((f"{group}/{key}", number, row["seed"]))
                values.setdefault(f"{group}/mean/{key}", []).append(number)
    return out + [(tag, sum(v) / len(v), 0) for tag, v in values.items()]


def _share_suffix(share: Any) -> str:
    """``@demo<share>`` for a row or entry from a share of the demonstration; "" for all of it."""
    number = _number(share)
    return "" if number is None or number == 1.0 else f"@demo{number:g}"


def benchmark_scalars(layout: RunLayout) -> list[Scalar]:
    """:func:`table_scalars` of ``benchmark/queries.csv``; ``<method>/success_vs_queries``: the
    success rate of each of the method's settings at step = its mean expert queries per seed
    (rounded), in the order of the queries, so TensorBoard draws success against queries;
    ``meta_training_queries/<what>``."""
    summary = read_json(layout.benchmark_summary, "the benchmark summary")
    out = table_scalars(layout.benchmark_table)
    entries = sorted(summary["entries"], key=lambda e: (e["method"], e["mean_queries"]))
    out += [
        (
            f"{e['method']}{_share_suffix(e.get('demo_fraction'))}/success_vs_queries",
            e["success_rate"],
            round(e["mean_queries"]),
        )
        for e in entries
    ]
    return out + [(f"meta_training_queries/{what}", n, 0) for what, n in summary["meta_training_queries"].items()]


def write_tensorboard(layout: RunLayout, runs: Mapping[str, Sequence[Scalar]]) -> list[Path]:
    """Replace the event files of every namespace of ``runs`` (e.g. ``{"mapper/dm": [...]}``) with
    its scalars, each tag prefixed by its namespace; returns the namespaces' folders.

    Raises:
        UserError: tensorboard is not installed.
    """
    writer_class = require_tensorboard()

    def write(namespace: str, scalars: Sequence[Scalar], folder: Path) -> None:
        writer = writer_class(log_dir=str(folder))
        try:
            for tag, value, step in scalars:
                number = _number(value)
                if number is not None:
                    writer.add_scalar(f"{namespace}/{tag}", number, int(step))
        finally:
            writer.close()

    folders = []
    for namespace, scalars in runs.items():
        # staged beside tb/, so a TensorBoard watching it never reads a half-written namespace
        folders.append(
            atomic_folder(
                layout.tb_run(namespace), functools.partial(write, namespace, scalars), staging_in=layout.root
            )
        )
    return folders


def _leaves(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Every (``a/b/c``, value) of a nested mapping."""
    out = []
    for key, value in data.items():
        tag = f"{prefix}{key}"
        out += _leaves(value, tag + "/") if isinstance(value, Mapping) else [(tag, value)]
    return out


def _number(value: Any) -> float | None:
    """``value`` as a float when it is a finite number or a boolean, else None."""
    if isinstance(value, (bool, int, float)) and math.isfinite(value):
        return float(value)
    return None
