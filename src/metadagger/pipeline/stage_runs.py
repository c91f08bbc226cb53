"""How a stage runs on its run folder: alone (the folder's write lock), with its config written
first and put back when it refuses, and with its wall time recorded in ``stage_times.json``."""

from __future__ import annotations

import contextlib
import datetime
import functools
import threading
import time
from typing import Any, Callable, Concatenate, Iterator, ParamSpec, TypeVar

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


#: How often a running stage writes the time it has spent so far: a call killed without a word
#: (SIGKILL, a machine that stops) loses at most this much of its time.
HEARTBEAT_SECONDS = 60.0


def _timed(stage: Callable[..., R], layout: RunLayout, config: RunConfig, *args: Any, **kwargs: Any) -> R:
    """``stage(...)``, its wall time added to ``RUN/stage_times.json``: at the start, every
    :data:`HEARTBEAT_SECONDS` while it runs (marked ``stopped``, as a call that ends unannounced
    leaves it) and when it finishes or is stopped (SIGTERM, Ctrl-C). The time a resumed run spent
    still counts; a run folder made in code, without a ``config.yaml``, records none."""
    if not layout.config.is_file():
        return stage(layout, config, *args, **kwargs)
    call = StageCall(layout, stage.__name__.removeprefix("stage_"))
    call.record(finished=False)
    try:
        with _beating(call):
            result = stage(layout, config, *args, **kwargs)
    except KeyboardInterrupt:
        call.record(finished=False)
        raise
    except BaseException:
        call.forget()
        raise
    call.record(finished=True)
    return result


@contextlib.contextmanager
def _beating(call: "StageCall") -> Iterator[None]:
    """Within: ``call`` written every :data:`HEARTBEAT_SECONDS` by a thread, stopped on the way out."""
    done = threading.Event()

    def beat() -> None:
        while not done.wait(HEARTBEAT_SECONDS):
            try:
                call.record(finished=False)
            except (OSError, UserError):  # a disk that refuses now: the call's last record says why
                pass

    heart = threading.Thread(target=beat, name=f"stage-time-{call.stage}", daemon=True)
    heart.start()
    try:
        yield
    finally:
        done.set()
        heart.join()


class StageCall:
    """One call of a stage in ``stage_times.json``: ``seconds`` (this call's), ``total_seconds``
    (all calls', this one's so far included), ``finished`` (when it was last written, UTC, ISO
    8601), ``stopped`` and ``earlier_seconds`` (the calls' before this one) while the call has not
    finished, and the source commits and CPUs of all its calls (``commits``, ``cpus``: each once,
    in order of first use)."""

    def __init__(self, layout: RunLayout, stage: str) -> None:
        self.layout, self.stage, self.start = layout, stage, time.perf_counter()
        self.before = self._times().get(stage, {})
        self.earlier = float(self.before.get("total_seconds", 0.0))
        # what made this call, found once (each heartbeat writes the same)
        self.commits = _once(self.before.get("commits", []), source_revision() or "unknown")
        self.cpus = _once(self.before.get("cpus", []), machine_description()["cpu"])

    def _times(self) -> dict[str, Any]:
        path = self.layout.stage_times
        return read_json(path, "the stage times") if path.is_file() else {}

    def record(self, *, finished: bool) -> None:
        """Write this call's time so far; ``finished=False`` marks it as not finished."""
        seconds = time.perf_counter() - self.start
        times = self._times()
        times[self.stage] = {
            "seconds": round(seconds, 3),
            "total_seconds": round(self.earlier + seconds, 3),
            "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "commits": self.commits,
            "cpus": self.cpus,
            **({} if finished else {"stopped": True, "earlier_seconds": round(self.earlier, 3)}),
        }
        write_json(self.layout.stage_times, times)

    def forget(self) -> None:
        """Put the stage's entry back as it was before this call (a call that failed counts no time)."""
        times = self._times()
        if self.before:
            times[self.stage] = self.before
        else:
            times.pop(self.stage, None)
        if times:
            write_json(self.layout.stage_times, times)
        else:
            self.layout.stage_times.unlink(missing_ok=True)


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
