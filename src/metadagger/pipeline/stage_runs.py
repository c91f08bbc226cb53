"""How a stage runs on its run folder: alone (the folder's write lock), with its config written
first and put back when it refuses, and with its wall time recorded in ``stage_times.json``."""

from __future__ import annotations

import datetime
import functools
import time
from typing import Any, Callable, Concatenate, ParamSpec, TypeVar

from metadagger.errors import UserError
from metadagger.pipeline.run_config import RunConfig, save_run
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import run_lock
from metadagger.utils.device import use_device
from metadagger.utils.io import atomic_write, read_json, write_json
from metadagger.utils.kernels import machine_description
from metadagger.utils.yaml_config import dump_yaml
from metadagger.version import source_revision

P = ParamSpec("P")
R = TypeVar("R")


def _timed(stage: Callable[..., R], layout: RunLayout, config: RunConfig, *args: Any, **kwargs: Any) -> R:
    """``stage(...)``, its wall time added to ``RUN/stage_times.json`` when it finishes or is
    stopped (SIGTERM, Ctrl-C: the time a resumed run spent still counts); a run folder made in
    code, without a ``config.yaml``, records none."""
    start = time.perf_counter()

    def record(stopped: bool) -> None:
        if layout.config.is_file():
            record_stage_time(
                layout, stage.__name__.removeprefix("stage_"), time.perf_counter() - start, stopped=stopped
            )

    try:
        result = stage(layout, config, *args, **kwargs)
    except KeyboardInterrupt:
        record(stopped=True)
        raise
    record(stopped=False)
    return result


def record_stage_time(layout: RunLayout, stage: str, seconds: float, *, stopped: bool = False) -> None:
    """Add one call of ``stage`` to the run's stage times: ``seconds`` (this call's),
    ``total_seconds`` (all calls'), ``finished`` (when it ended, UTC, ISO 8601), ``stopped``
    (only while the last call was stopped before it finished), and the source commits and CPUs of
    all its calls (``commits``, ``cpus``: each once, in order of first use)."""
    times = read_json(layout.stage_times, "the stage times") if layout.stage_times.is_file() else {}
    before = times.get(stage, {})
    total = float(before.get("total_seconds", 0.0)) + seconds
    cpu = machine_description()["cpu"]
    times[stage] = {
        "seconds": round(seconds, 3),
        "total_seconds": round(total, 3),
        "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commits": _once(before.get("commits", []), source_revision() or "unknown"),
        "cpus": _once(before.get("cpus", []), cpu),
        **({"stopped": True} if stopped else {}),
    }
    write_json(layout.stage_times, times)


def _once(seen: list[str], item: str) -> list[str]:
    return list(seen) if item in seen else [*seen, item]


def records_config(
    stage: Callable[Concatenate[RunLayout, RunConfig, P], R],
) -> Callable[Concatenate[RunLayout, RunConfig, P], R]:
    """``stage(layout, config, ...)`` run with ``config`` as the run's ``config.yaml``: written first
    when the file says otherwise (``--set`` overrides), and put back as it was when the stage
    refuses (a :class:`UserError`), so a refused command leaves the run's config unchanged. A
    folder without a ``config.yaml`` (a config made in code) gets none. The stage holds the run
    folder's write lock (a second writer is refused at once) and computes on the run's device
    (:func:`~metadagger.utils.device.use_device`; its workers too)."""

    @functools.wraps(stage)
    def wrapper(layout: RunLayout, config: RunConfig, *args: P.args, **kwargs: P.kwargs) -> R:
        use_device(config.device)
        with run_lock(layout.root):  # one writer per run folder (runfolder/lock.py)
            before = layout.config.read_bytes() if layout.config.is_file() else None
            if before is None or before == dump_yaml(config).encode():
                return _timed(stage, layout, config, *args, **kwargs)
            save_run(layout.root, config)
            try:
                return _timed(stage, layout, config, *args, **kwargs)
            except UserError:
                atomic_write(layout.config, lambda tmp: tmp.write_bytes(before))
                raise

    return wrapper
