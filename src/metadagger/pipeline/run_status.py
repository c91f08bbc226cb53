"""Where a run folder stands, read from its files alone: who writes it now, each stage's state and
wall time (``stage_times.json``), and how many of its seeds each per-seed stage has logged.

Nothing is loaded or checked against the config here: a stage that finished under other settings
is made again by the next ``reproduce``, which says so. This is the view of a run that is long, or
resumed across sittings: how far it is, and whether a process is on it.
"""

from __future__ import annotations

import datetime
import json
import os
import socket
from pathlib import Path
from typing import Any, Iterable

from metadagger.evaluation.report.run import duration
from metadagger.evaluation.report.tables import markdown_table
from metadagger.metal_dagger.store import PairStore
from metadagger.pipeline.run_config import RunConfig
from metadagger.pipeline.stages import STAGES as REPRODUCE_STAGES
from metadagger.runfolder.driver import RowLog
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import LOCK_FILE
from metadagger.utils.io import read_json

#: The stages ``reproduce`` runs that write a run's artifacts, in its order (the report is built from their files).
STAGES = tuple(stage for stage in REPRODUCE_STAGES if stage != "report")


def run_status(layout: RunLayout, config: RunConfig) -> list[str]:
    """Lines that say where the run stands: its writer, then one table row per stage."""
    writer = current_writer(layout.root)
    times = read_json(layout.stage_times, "the stage times") if layout.stage_times.is_file() else {}
    running = _running_stage(times) if writer else None
    rows = []
    for stage in STAGES:
        entry = times.get(stage)
        if not _configured(config, stage):
            rows.append((stage, "not in this config", "-", "-", "-"))
            continue
        seeds = _seeds_logged(layout, config, stage)
        state = _state(entry, running=stage == running)
        if stage == running and entry is not None:
            state += _left(entry, seeds)
        rows.append(
            (
                stage,
                state,
                duration(entry["total_seconds"]) if entry else "-",
                _local(entry["finished"]) if entry else "-",
                ", ".join(f"{done}/{asked}{f' {name}' if name else ''}" for name, done, asked in seeds) or "-",
            )
        )
    head = f"run {layout.root}: task {config.task}, preset {config.preset}"
    who = f"written now by {writer}" if writer else "no process writes it now"
    header = ("stage", "state", "wall time, all calls", "last written", "seeds logged")
    return [head, who, "", *markdown_table(header, rows)]


def _configured(config: RunConfig, stage: str) -> bool:
    """Whether the run's config runs ``stage`` (MDI and the benchmark are optional sections)."""
    return {"mdi": config.mdi, "benchmark": config.benchmark}.get(stage, True) is not None


def current_writer(root: Path) -> str | None:
    """The process that holds the run folder's write lock, described, where its lock file names a
    live process of this host; None otherwise. Reads the lock file only, never takes the lock."""
    path = Path(root) / LOCK_FILE
    try:
        holder = json.loads(path.read_text(encoding="utf-8"))
        pid, host = int(holder["pid"]), str(holder["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if host != socket.gethostname() or not _alive(pid):
        return None
    return f"pid {pid} on {host} (`{holder.get('command', '?')}`, since {holder.get('since', '?')})"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _running_stage(times: dict[str, Any]) -> str | None:
    """The stage a live writer is in: the last written of those whose call has not finished (its
    time so far is the last heartbeat's, plus the time since)."""
    unfinished = [(e.get("finished", ""), s) for s, e in times.items() if isinstance(e, dict) and e.get("stopped")]
    return max(unfinished)[1] if unfinished else None


def _state(entry: dict[str, Any] | None, *, running: bool) -> str:
    if entry is None:
        return "not run"
    if running:
        return f"running ({duration(entry['seconds'] + _since(entry['finished']))} into this call)"
    return "stopped (resumes)" if entry.get("stopped") else "finished"


def _since(iso: str) -> float:
    """Seconds from an ISO 8601 time to now (0 where it does not read or lies ahead)."""
    try:
        then = datetime.datetime.fromisoformat(iso)
    except ValueError:
        return 0.0
    return max(0.0, (datetime.datetime.now(datetime.timezone.utc) - then).total_seconds())


def _local(iso: str) -> str:
    """An ISO 8601 time as this machine's local ``YYYY-MM-DD HH:MM``."""
    try:
        return datetime.datetime.fromisoformat(iso).astimezone().strftime("%Y-%m-%d %H:%M")
    except ValueError:
        return iso


Logged = list[tuple[str, int, int]]
"""A stage's seed sets: (name, seeds logged, seeds asked); the benchmark's are named."""


def _seeds_logged(layout: RunLayout, config: RunConfig, stage: str) -> Logged:
    """The seeds a per-seed stage's resume log holds, of those asked (both seed sets of the
    benchmark); [] for a stage that works on the whole run at once."""
    if stage == "pairs":
        return [_count("", _pair_seeds(layout), config.pairs.seeds)]
    if stage == "evaluate":
        return [_count("", _logged(layout.eval_log("mdm")), config.evaluate.seeds)]
    if stage == "mdi" and config.mdi is not None:
        return [_count("", _logged(layout.eval_log("mdi")), config.mdi.seeds)]
    if stage == "benchmark" and config.benchmark is not None:
        sets = [_count("unseen", _logged(layout.benchmark_log), config.benchmark.seeds)]
        if config.benchmark.confirm_seeds:
            confirm = _logged(layout.confirmation().benchmark_log)
            sets.append(_count("confirmation", confirm, config.benchmark.confirm_seeds))
        return sets
    return []


def _count(name: str, logged: set[int], asked: Iterable[int]) -> tuple[str, int, int]:
    asked = list(asked)
    return name, sum(seed in logged for seed in asked), len(asked)


def _left(entry: dict[str, Any], seeds: Logged) -> str:
    """``; about N left`` for a running per-seed stage, at the rate its logged seeds took so far (all
    calls, this one's time to now included); "" before its first seed is logged."""
    done, asked = sum(d for _, d, _ in seeds), sum(a for _, _, a in seeds)
    if not done or done >= asked:
        return ""
    spent = entry["total_seconds"] + _since(entry["finished"])
    return f"; about {duration(spent / done * (asked - done))} left"


def _logged(path: Path) -> set[int]:
    return set(RowLog(path).stamps()) if path.is_file() else set()


def _pair_seeds(layout: RunLayout) -> set[int]:
    if not layout.pairs_dir.is_dir():
        return set()
    return {int(record["seed"]) for record in PairStore(layout.pairs_dir).records()}
