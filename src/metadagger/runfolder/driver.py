"""The one per-seed driver: plan the missing work, run it on an executor, save, log.

Pairs, MDM and MDI differ only in what they compute for a seed. How seeds are scheduled, logged,
resumed and written is the same for all of them and lives here:

1. :func:`plan`: for every seed, the methods whose rows are missing from the protocol's log, or
   were made from other inputs (another pi*, another mapper, other settings: the *stamp* of each
   method, see :mod:`metadagger.runfolder.stamps`). Stale rows are redone only when asked (``rebuild``);
   otherwise the plan stops with one line naming what changed.
2. :func:`drive`: each seed's job goes to the executor; as each result arrives, the driver alone
   saves its artifacts (heads, pair tensors) and then appends the log, so a seed counts as done
   only once its artifacts are on disk and a killed run resumes with the missing work.
3. :meth:`RowLog.rows`: the current rows (the latest made from the current stamps) for the
   requested seeds and methods, from which the protocol writes its tables.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Protocol, Sequence

from metadagger.errors import CheckpointError, UserError
from metadagger.runfolder.stamps import describe_changes
from metadagger.utils.executors import make_executor
from metadagger.utils.jsonl import append_line, dumps_line, read_lines
from metadagger.utils.progress import progress_bar

if TYPE_CHECKING:
    from metadagger.tasks.base import Task

Stamp = Mapping[str, Any]
"""What one method's rows are made from (plain JSON data)."""


class SeedLog(Protocol):
    """A protocol's resume log, as the driver sees it."""

    def stamps(self) -> dict[int, dict[str, Stamp]]:
        """For every logged seed, the stamp of each method logged for it (latest wins)."""

    def append(self, result: Mapping[str, Any], stamps: Mapping[str, Stamp]) -> None:
        """Record a finished seed's result, each method's rows with its stamp."""


class RowLog:
    """``*.jsonl`` of evaluation rows: one line per finished job, ``{"seed", "entries": {method:
    {"stamp", "rows"}}}``; a worker's result carries ``entries: {method: [rows]}``. A method's
    latest entry for a seed supersedes earlier ones; a line without entries is a corrupt line
    (a :class:`CheckpointError` naming the file)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def _entries(self) -> dict[int, dict[str, dict[str, Any]]]:
        latest: dict[int, dict[str, dict[str, Any]]] = {}
        for record in read_lines(self.path, called="row record"):
            entries = record.get("entries")
            if not isinstance(entries, dict):
                raise CheckpointError(
                    f"{self.path} has a row record without its entries: {str(record)[:80]}; "
                    "delete that line and re-run the stage"
                )
            for method, entry in entries.items():
                latest.setdefault(int(record["seed"]), {})[method] = entry
        return latest

    def stamps(self) -> dict[int, dict[str, Stamp]]:
        """See :meth:`SeedLog.stamps`."""
        return {seed: {m: e["stamp"] for m, e in entries.items()} for seed, entries in self._entries().items()}

    def append(self, result: Mapping[str, Any], stamps: Mapping[str, Stamp]) -> None:
        """See :meth:`SeedLog.append` (only the driver writes)."""
        entries = {m: {"stamp": dict(stamps[m]), "rows": rows} for m, rows in result["entries"].items()}
        append_line(self.path, dumps_line({"seed": int(result["seed"]), "entries": entries}))

    def rows(self, seeds: Iterable[int], stamps: Mapping[str, Stamp]) -> list[dict[str, Any]]:
        """The rows of ``seeds`` (in that order) for the methods of ``stamps`` (in that order),
        only those made from the given stamps."""
        latest = self._entries()
        out = []
        for seed in seeds:
            for method, stamp in stamps.items():
                entry = latest.get(int(seed), {}).get(method)
                if entry is not None and entry["stamp"] == dict(stamp):
                    out += entry["rows"]
        return out


@dataclass(frozen=True)
class StageOptions:
    """How a stage runs its work: what it does with stale rows, where its per-seed jobs run, and
    whether it draws progress bars. Every stage takes one."""

    rebuild: bool = False
    """Redo work made from other inputs (another pi*, mapper or settings) instead of refusing."""
    executor: str = "local"
    """``local`` (a process pool), ``ray`` or ``inline`` (:func:`metadagger.utils.executors.make_executor`)."""
    workers: int | None = None
    """Parallel workers; default: this machine's cores, or the Ray cluster's CPUs."""
    address: str | None = None
    """Ray cluster address; None starts a local Ray instance (executor ``ray`` only)."""
    progress: bool = True
    """Draw progress bars."""


@dataclass(frozen=True)
class SeedJob:
    """What every per-seed job carries to its worker (picklable; workers share nothing else);
    protocols add their own fields."""

    task: Task
    pistar: str
    """pi*'s file."""
    seed: int
    methods: tuple[str, ...]
    """The methods this seed still needs (from :func:`plan`)."""


@dataclass(frozen=True)
class SeedPlan:
    """The methods one seed still needs."""

    seed: int
    methods: tuple[str, ...]


def plan(
    seeds: Sequence[int], stamps: Mapping[str, Stamp], log: SeedLog, *, rebuild: bool, called: str, fix: str
) -> list[SeedPlan]:
    """The missing work: for each seed, the methods of ``stamps`` not logged with these stamps.

    Args:
        seeds: the seeds asked for.
        stamps: each method's current stamp.
        log: the protocol's resume log.
        rebuild: redo rows made from other inputs; without it, such rows are an error.
        called: the protocol's name for messages (``MDM evaluation``, ``pairs``).
        fix: the command that rebuilds, for the error message.

    Raises:
        UserError: rows made from other inputs exist and ``rebuild`` is off; the message names
            the changed fields of the first such method.
    """
    logged = log.stamps()
    todo, stale = [], {}
    for seed in seeds:
        methods = []
        for method, stamp in stamps.items():
            old = logged.get(int(seed), {}).get(method)
            if old is not None and old != dict(stamp):
                stale.setdefault(method, (old, []))[1].append(seed)
                if not rebuild:
                    continue
            if old != dict(stamp):
                methods.append(method)
        if methods:
            todo.append(SeedPlan(int(seed), tuple(methods)))
    if stale and not rebuild:
        method, (old, which) = next(iter(stale.items()))
        changes = "; ".join(describe_changes(old, stamps[method])) or "stamp format"
        of_method = f" of {method!r}" if len(stamps) > 1 else ""  # a stage of one kind of work needs no name for it
        raise UserError(
            f"{called}{of_method} on {len(which)} seed(s) (e.g. {which[0]}) was made from other inputs ({changes}); "
            f"{fix}"
        )
    return todo


def drive(
    work: Callable[[Any], dict[str, Any]],
    jobs: Sequence[Any],
    *,
    log: SeedLog,
    stamps: Mapping[str, Stamp],
    save: Callable[[dict[str, Any]], None] | None = None,
    options: StageOptions = StageOptions(),
    desc: str = "seeds",
) -> None:
    """Run ``work`` on every job, in parallel; as each result arrives, ``save`` its artifacts and
    then append it to ``log`` with its methods' stamps. A job whose ``work`` returns a list (a
    block of seeds, :func:`metadagger.metal_dagger.lane_blocks.in_blocks`) has each of its results saved and
    logged in turn."""
    if not jobs:
        return
    with make_executor(options.executor, workers=options.workers, address=options.address) as pool:
        for result in progress_bar(
            pool.imap_unordered(work, jobs), total=len(jobs), desc=desc, enabled=options.progress
        ):
            for one in result if isinstance(result, list) else [result]:
                if save is not None:
                    save(one)
                log.append(one, stamps)
