"""``bench reproduce``: whole runs of a preset as it is and with overrides, side by side.

Each arm is one ``metadagger reproduce`` in a fresh process, on a scratch folder: wall seconds, each
stage's seconds (the run's ``stage_times.json``), the peak resident memory of its largest process
(the driver or a worker) and digests of the tables it made. The overrides are what a lane width
needs (``--set benchmark.lanes=32 --set pairs.lanes=15 ...``), so one call measures what lanes buy
a whole run.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from metadagger.cli.bench import machine_block
from metadagger.errors import UserError
from metadagger.runfolder.machine_cache import CACHE_ENV, OFF

#: The tables whose digests say whether two arms made the same numbers.
TABLES = ("eval/mdm.csv", "benchmark/queries.csv")
#: The arms, in the order they run.
ARMS = ("preset", "with overrides")


def bench_reproduce(
    task: str,
    *,
    preset: str = "quick",
    overrides: Sequence[str] = (),
    workers: int | None = None,
    progress: bool = True,
) -> dict:
    """Time ``reproduce --task task --preset preset`` as the preset is and with ``overrides``, one after
    the other on this machine; their seconds, the ratio, peak memory and the tables' digests."""
    from metadagger.pipeline.run_config import resolve_config

    if not overrides:
        raise UserError("bench reproduce compares the preset with overrides; give at least one --set")
    resolve_config(task, preset, overrides=overrides)  # a bad task, preset or override is named before any work
    arms = {}
    with tempfile.TemporaryDirectory() as tmp:
        for arm, sets in zip(ARMS, ((), overrides)):
            out = Path(tmp) / arm.replace(" ", "-")
            command = [sys.executable, "-m", "metadagger.cli", "reproduce", "--task", task, "--preset", preset]
            command += ["--out", str(out), *(a for s in sets for a in ("--set", s))]
            command += [] if workers is None else ["--workers", str(workers)]
            arms[arm] = _timed(command, out, arm)
            if progress:
                print(f"bench reproduce: {arm}: {arms[arm]['seconds']:.1f} s", file=sys.stderr, flush=True)
    return {
        "task": task,
        "preset": preset,
        "overrides": list(overrides),
        "workers": workers,
        "arms": arms,
        "speedup": arms[ARMS[0]]["seconds"] / arms[ARMS[1]]["seconds"],
        "machine": machine_block(),
    }


def _timed(command: list[str], out: Path, arm: str) -> dict:
    """One arm: wall seconds, the run's stage seconds, the largest process's peak memory, the digests."""
    with tempfile.TemporaryFile(mode="w+") as errors:
        start = time.perf_counter()
        # each arm trains its own pi*: one taken from the machine's cache would time nothing
        environment = {**os.environ, CACHE_ENV: OFF}
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=errors, env=environment)
        # wait4's usage holds the child's peak and its reaped workers' (the largest of them)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        seconds = time.perf_counter() - start
        if proc.returncode != 0:
            errors.seek(0)
            raise UserError(f"bench reproduce: the {arm} run failed: {errors.read().strip()[-500:]}")
    stages = json.loads((out / "stage_times.json").read_text())
    return {
        "seconds": seconds,
        "stages": {name: round(entry["seconds"], 3) for name, entry in stages.items()},
        "peak_memory_mb": usage.ru_maxrss / 1024,
        "sha256": {
            table: hashlib.sha256((out / table).read_bytes()).hexdigest() for table in TABLES if (out / table).is_file()
        },
    }
