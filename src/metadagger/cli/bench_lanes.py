"""``bench lanes``: one benchmark seed of a run at several lane widths, each in a fresh process."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from metadagger.cli.bench import machine_block
from metadagger.errors import UserError
from metadagger.runfolder.layout import RunLayout


def bench_lanes(
    run: str | Path, *, seed: int | None = None, widths: Sequence[int] = (1, 32), overrides: Sequence[str] = ()
) -> dict:
    """Time one benchmark seed of ``run`` (its config, with ``overrides``) at each lane width, side by side.

    Each width runs the seed's whole benchmark (every method of the config) in a fresh process on
    a scratch copy of the run that shares its pi*, pairs and mappers, with one worker: wall seconds, the
    worker's CPU seconds and peak resident memory, and a digest of the rows (the same digest for
    two widths would mean the same numbers; different widths round the trunk's last bits
    differently, so they need not agree). The run's own rows are untouched.
    """
    import dataclasses

    from metadagger.imitation.lanes import MAX_LANES
    from metadagger.pipeline.stages import load_run

    run = Path(run)
    config = load_run(run, overrides)
    if config.benchmark is None:
        raise UserError(f"run {run} has no benchmark section; bench lanes times one of its benchmark seeds")
    if not widths or any(not 1 <= w <= MAX_LANES for w in widths):
        raise UserError(f"bench lanes needs --lanes from 1 to {MAX_LANES}, got {list(widths)}")
    seed = config.benchmark.seeds[0] if seed is None else seed
    dataclasses.replace(config.benchmark, seeds=(seed,))  # a bad seed or override is named before any work
    layout = RunLayout(run)
    for path, what in ((layout.pistar, "pi*"), (layout.root / "mappers", "the mappers")):
        if not path.exists():
            raise UserError(
                f"bench lanes needs {what} of run {run} ({path} is missing); run metadagger reproduce first"
            )
    timings = {}
    for width in widths:
        # the pins first, before the child's numpy loads, as the command line does
        code = (
            "import sys, metadagger; metadagger.pin_cpu_kernels(); from metadagger.cli.bench_lanes import lanes_child"
        )
        child = [sys.executable, "-c", code + "; lanes_child(sys.argv[1:])"]
        args = [str(run), str(seed), str(width), *overrides]
        done = subprocess.run([*child, *args], capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise UserError(f"bench lanes: the benchmark seed at width {width} failed: {done.stderr.strip()[-500:]}")
        timings[str(width)] = json.loads(done.stdout.strip().splitlines()[-1])
    first = timings[str(widths[0])]
    return {
        "run": str(run),
        "seed": seed,
        "overrides": list(overrides),
        "widths": timings,
        "speedup_wall": {k: first["wall_seconds"] / v["wall_seconds"] for k, v in timings.items()},
        "speedup_cpu": {k: first["worker_cpu_seconds"] / v["worker_cpu_seconds"] for k, v in timings.items()},
        "machine": machine_block(),
    }


def lanes_child(argv: list[str]) -> None:
    """``bench lanes``' measurement of one width, in a process of its own: RUN SEED WIDTH [OVERRIDE ...].

    The seed runs in this process (the inline executor), so its CPU time and peak memory are this
    process's; prints them as one JSON line.
    """
    import dataclasses
    import resource

    import torch

    from metadagger.pipeline.stages import load_run, stage_benchmark
    from metadagger.runfolder.driver import StageOptions

    torch.set_num_threads(1)  # as in every worker
    run, seed, width, overrides = argv[0], int(argv[1]), int(argv[2]), argv[3:]
    config = load_run(run, overrides)
    bench = dataclasses.replace(config.benchmark, seeds=(seed,), lanes=width)
    config = dataclasses.replace(config, benchmark=bench)
    source = RunLayout(run)
    with tempfile.TemporaryDirectory(prefix="metadagger-bench-") as tmp:
        scratch = RunLayout(tmp)
        for name in ("pistar", "pairs", "mappers"):  # read only: the mappers are checked against the pairs
            if (source.root / name).exists():
                (scratch.root / name).symlink_to((source.root / name).resolve())
        wall, cpu = time.perf_counter(), time.process_time()
        stage_benchmark(scratch, config, options=StageOptions(executor="inline", progress=False))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        digest = hashlib.sha256(scratch.benchmark_table.read_bytes()).hexdigest()
    result = {
        "wall_seconds": wall,
        "worker_cpu_seconds": cpu,
        "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "rows_sha256": digest,
    }
    print(json.dumps(result))
