"""Calibration records: a variant of a task read on pair seeds, kept so its docs page can show why a
variant was chosen (``scripts/calibrate.sh`` makes the run, ``results calibration`` keeps it).

A record is ``results/calibration/<task>/<name>.json``: the settings in which the run departs from
the task's quick preset (the calibration's own fixed settings left out), pi*'s success on its unseen
seeds, BC, BC refitted, DART and DAgger after their last round (successes, labels, loss on the
held-out expert states), DAgger paired against BC refitted and against DART at its label count, each
method's held-out loss paired with DAgger's, and the commit that made it. The ``calibration TASK``
block (:mod:`metadagger.results.blocks`) is the table of a task's records.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Iterator, Mapping

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.summary import last_round, last_rows
from metadagger.evaluation.paired import paired_difference
from metadagger.evaluation.report.tables import markdown_table
from metadagger.pipeline.run_config import RunConfig, load_run, resolve_config
from metadagger.results.registry import REGISTRY
from metadagger.results.tables import whole_entries
from metadagger.runfolder.driver import RowLog
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json, write_json

#: Where the records lie in the registry folder.
CALIBRATION = "calibration"

#: Settings every calibration run sets (scripts/calibrate.sh): not what tells variants apart.
FIXED = (
    "pairs.seeds",
    "benchmark.seeds",
    "benchmark.methods",
    "benchmark.oracle",
    "benchmark.confirm_seeds",
    "benchmark.held_out_every",
    "preset",
)

#: The methods a calibration reads, each at its last round.
METHODS = ("bc", "bc-refit", "dart", "dagger")


def _flat(data: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in data.items():
        if isinstance(value, Mapping) and value:
            yield from _flat(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def departures(config: RunConfig) -> dict[str, Any]:
    """The settings of a run's ``config`` that differ from its task's quick preset (None: one the
    run does not have), the calibration's fixed ones (:data:`FIXED`) left out."""
    ours = dict(_flat(dataclasses.asdict(config)))
    preset = dict(_flat(dataclasses.asdict(resolve_config(config.task, "quick"))))
    return {
        key: ours.get(key)
        for key in sorted(ours.keys() | preset.keys())
        if preset.get(key) != ours.get(key) and not key.startswith(FIXED) and not key.endswith("metadagger_version")
    }


def _last(entries: list[dict[str, Any]], method: str) -> dict[str, Any]:
    last = last_round(whole_entries(entries), method)
    if last is None:
        methods = ", ".join(METHODS)
        raise UserError(
            f"the benchmark has no {method!r} rows; calibrate with scripts/calibrate.sh, which runs {methods}"
        )
    keys = ("successes", "seeds", "mean_queries", "mean_expert_loss")
    return {key: last.get(key) for key in keys}


def _paired(comparisons: list[dict[str, Any]], method: str, against: str) -> dict[str, Any]:
    rows = [row for row in comparisons if row["method"] == method and row["against"] == against]
    if not rows:
        raise UserError(f"the benchmark compares no {method!r} row with {against!r}; rerun its benchmark stage")
    row = max(rows, key=lambda row: int(row["setting"] or 0))
    return {key: row[key] for key in ("difference", "ci_low", "ci_high", "seeds")}


def _held_out_losses(run: Path) -> dict[str, dict[str, float]]:
    """Each method's loss on the held-out expert states after its last round, minus DAgger's after
    its last, paired over the seeds (mean with its 95% interval); {} where the run held none out."""
    log = RowLog(RunLayout(run).benchmark_log)
    held = [
        row
        for seed, stamps in log.stamps().items()
        for row in log.rows([seed], stamps)
        if row.get("expert_loss") is not None
    ]
    last = {method: last_rows(held, method) for method in METHODS}
    dagger = last["dagger"]
    return {
        method: paired_difference([by_seed[s]["expert_loss"] for s in seeds], [dagger[s]["expert_loss"] for s in seeds])
        for method, by_seed in last.items()
        if method != "dagger" and (seeds := sorted(set(by_seed) & set(dagger)))
    }


def calibration_record(run: Path) -> dict[str, Any]:
    """The record of calibration run folder ``run`` (see the module docstring)."""
    config = load_run(run)
    summary = read_json(run / "benchmark" / "summary.json", "benchmark summary")
    pistar = read_json(run / "pistar" / "metrics.json", "pi* metrics")["unseen_seeds"]
    commits = read_json(run / "stage_times.json", "stage times")["benchmark"]["commits"]
    return {
        "task": config.task,
        "settings": departures(config),
        "pistar_unseen": {"successes": pistar["successes"], "episodes": pistar["episodes"]},
        "methods": {method: _last(summary["entries"], method) for method in METHODS},
        "dagger_vs_refit": _paired(summary["comparisons"], "dagger", "bc-refit"),
        "dagger_vs_dart": _paired(summary["comparisons"], "dagger", "dart"),
        "loss_vs_dagger": _held_out_losses(run),
        "commits": commits,
    }


def add_calibration(run: str | Path, name: str, registry: str | Path = REGISTRY) -> Path:
    """Keep calibration run ``run`` as record ``name`` of its task (see the module docstring)."""
    if not name.replace("-", "").replace("_", "").isalnum():
        raise UserError(f"--name must be letters, digits, '-' and '_', got {name!r}; e.g. faults-10")
    record = calibration_record(Path(run))
    return write_json(Path(registry) / CALIBRATION / record["task"] / f"{name}.json", {"name": name, **record})


def _setting(value: Any) -> str:
    """A setting as a row shows it: None as "none", a run of consecutive seeds as ``first-last``."""
    if value is None:
        return "none"
    if isinstance(value, list) and len(value) > 1 and value == list(range(value[0], value[0] + len(value))):
        return f"{value[0]}-{value[-1]}"
    return str(value)


def _share(method: Mapping[str, Any]) -> str:
    return f"{method['successes']}/{method['seeds']}"


def _difference(row: Mapping[str, Any]) -> str:
    return f"{100 * row['difference']:+.0f} ({100 * row['ci_low']:+.0f} to {100 * row['ci_high']:+.0f})"


def _loss(method: Mapping[str, Any]) -> str:
    loss = method.get("mean_expert_loss")
    return "-" if loss is None else f"{loss:.2f}"


def _loss_difference(record: Mapping[str, Any], method: str) -> str:
    row = record.get("loss_vs_dagger", {}).get(method)
    return "-" if row is None else f"{row['difference']:+.2f} ({row['ci_low']:+.2f} to {row['ci_high']:+.2f})"


def calibration_table(root: Path, task: str) -> str:
    """A row per calibration record of ``task``: its departures from the quick preset, pi*'s unseen
    success, each method's success after its last round, DAgger's paired differences (points, with
    their 95% intervals), each method's loss on the held-out expert states and BC's and BC
    refitted's minus DAgger's, paired ("-" where the run did not measure it)."""
    folder = root / REGISTRY / CALIBRATION / task
    records = [read_json(path, "calibration record") for path in sorted(folder.glob("*.json"))]
    if not records:
        how = "run `bash scripts/calibrate.sh`, then `metadagger results calibration`"
        return f"No calibration of {task} is kept yet: {how}.\n"
    header = [
        "variant",
        "settings",
        "pi* unseen",
        "BC",
        "BC refitted",
        "DART",
        "DAgger",
        "DAgger - refitted",
        "DAgger - DART",
        "held-out loss (same order)",
        "loss - DAgger's: BC; BC refitted",
        "labels",
    ]
    rows = []
    for record in records:
        methods = record["methods"]
        settings = "; ".join(f"`{key}` {_setting(value)}" for key, value in record["settings"].items())
        rows.append(
            [
                record["name"],
                settings or "the quick preset's",
                f"{record['pistar_unseen']['successes']}/{record['pistar_unseen']['episodes']}",
                *(_share(methods[method]) for method in METHODS),
                _difference(record["dagger_vs_refit"]),
                _difference(record["dagger_vs_dart"]),
                " / ".join(_loss(methods[method]) for method in METHODS),
                "; ".join(_loss_difference(record, method) for method in ("bc", "bc-refit")),
                f"{methods['dagger']['mean_queries']:,.0f}",
            ]
        )
    return "\n".join(markdown_table(header, rows)) + "\n"
