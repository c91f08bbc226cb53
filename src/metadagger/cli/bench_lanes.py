"""``bench lanes`` and ``bench step``: one benchmark seed of a run, in a fresh process, at several
lane widths (wall and CPU seconds, memory), or at one width with its laned steps taken apart
(where a step's time goes, against the env's own step)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from metadagger.cli.bench import machine_block
from metadagger.errors import UserError
from metadagger.runfolder.layout import RunLayout


def bench_lanes(
    run: str | Path,
    *,
    seed: int | None = None,
    widths: Sequence[int] = (1, 32),
    overrides: Sequence[str] = (),
    repeats: int = 1,
) -> dict:
    """Time one benchmark seed of ``run`` (its config, with ``overrides``) at each lane width, side by side.

    Each width runs the seed's whole benchmark (every method of the config) in a fresh process on
    a scratch copy of the run that shares its pi*, pairs and mappers, with one worker: wall seconds, the
    worker's CPU seconds and peak resident memory, and a digest of the rows (the same digest for
    two widths would mean the same numbers; different widths round the trunk's last bits
    differently, so they need not agree). With ``repeats`` above 1 the widths take turns that many
    times: each width's seconds are the median and its peak memory the largest (a peak depends on
    how the heap happened to fill), every repeat listed. The run's own rows are untouched.
    """
    _check_widths(widths, "bench lanes")
    if repeats < 1:
        raise UserError(f"bench lanes needs --repeats of at least 1, got {repeats}")
    run, seed, _ = _checked(run, seed, overrides, "bench lanes")
    measured: dict[str, list[dict[str, Any]]] = {str(width): [] for width in widths}
    for _ in range(repeats):
        for width in widths:
            measured[str(width)].append(_in_child("lanes_child", run, seed, width, overrides))
    timings = {width: _over_repeats(each) for width, each in measured.items()}
    first = timings[str(widths[0])]
    return {
        "run": str(run),
        "seed": seed,
        "overrides": list(overrides),
        "repeats": repeats,
        "widths": timings,
        "speedup_wall": {k: first["wall_seconds"] / v["wall_seconds"] for k, v in timings.items()},
        "speedup_cpu": {k: first["worker_cpu_seconds"] / v["worker_cpu_seconds"] for k, v in timings.items()},
        "machine": machine_block(),
    }


def _over_repeats(each: list[dict[str, Any]]) -> dict[str, Any]:
    """One width's repeats in one entry: median seconds, the largest peak memory, the rows' digest
    (``same_rows``: whether every repeat made the same rows) and every repeat as measured."""
    return {
        "wall_seconds": statistics.median(r["wall_seconds"] for r in each),
        "worker_cpu_seconds": statistics.median(r["worker_cpu_seconds"] for r in each),
        "worker_peak_rss_mb": max(r["worker_peak_rss_mb"] for r in each),
        "rows_sha256": each[0]["rows_sha256"],
        "same_rows": len({r["rows_sha256"] for r in each}) == 1,
        "each": each,
    }


def bench_step(
    run: str | Path, *, seed: int | None = None, width: int | None = None, overrides: Sequence[str] = ()
) -> dict:
    """Where one laned benchmark step's time goes: one benchmark seed of ``run`` at lane width
    ``width`` (default: the run's ``benchmark.lanes``), in a fresh process, with the time inside
    :meth:`Lanes.step <metadagger.imitation.lanes.Lanes.step>` taken apart into the env's own steps
    (its physics and rendering: the floor on a CPU), the expert's labels of every state, pi*'s trunk
    forwards and the rest (stacking the batch, the heads' actions, recording); the head-only fits
    between rollouts and the env steps outside the lanes (the demonstrations) beside it.
    ``step_over_env`` is a laned step's time over the env's own steps inside it."""
    run, seed, config = _checked(run, seed, overrides, "bench step")
    width = config.benchmark.lanes if width is None else width
    _check_widths((width,), "bench step")
    parts = _in_child("step_child", run, seed, width, overrides)
    seconds = parts["seconds"]
    inside = seconds["lanes_step"]
    rest = inside - seconds["env_step"] - seconds["expert_labels"] - seconds["trunk_forward"]
    steps = parts["env_steps"]
    return {
        "run": str(run),
        "seed": seed,
        "width": width,
        "overrides": list(overrides),
        **parts,
        "rest_of_the_step": rest,
        "per_env_step_ms": {k: 1000 * v / steps for k, v in {**seconds, "rest_of_the_step": rest}.items()},
        "step_over_env": inside / seconds["env_step"],
        "machine": machine_block(),
    }


def _check_widths(widths: Sequence[int], command: str) -> None:
    """One error line, before any work, unless ``widths`` is a non-empty list of lane widths."""
    from metadagger.imitation.lanes import MAX_LANES

    if not widths or any(not 1 <= w <= MAX_LANES for w in widths):
        raise UserError(f"{command} needs --lanes from 1 to {MAX_LANES}, got {list(widths)}")


def _checked(run: str | Path, seed: int | None, overrides: Sequence[str], command: str) -> tuple[Path, int, Any]:
    """The run folder, the seed to time and the run's config; a bad run, seed or override is one
    error before any work."""
    from metadagger.pipeline.stages import load_run

    run = Path(run)
    config = load_run(run, overrides)
    if config.benchmark is None:
        raise UserError(f"run {run} has no benchmark section; {command} times one of its benchmark seeds")
    seed = config.spare_seed if seed is None else seed
    dataclasses.replace(config.benchmark, seeds=(seed,))  # a bad seed or override is named before any work
    layout = RunLayout(run)
    for path, what in ((layout.pistar, "pi*"), (layout.root / "mappers", "the mappers")):
        if not path.exists():
            raise UserError(f"{command} needs {what} of run {run} ({path} is missing); run metadagger reproduce first")
    return run, seed, config


def _in_child(child: str, run: Path, seed: int, width: int, overrides: Sequence[str]) -> dict[str, Any]:
    """``child`` of this module run in a fresh process on RUN SEED WIDTH [OVERRIDE ...]; its last JSON line."""
    # the pins first, before the child's numpy loads, as the command line does
    code = f"import sys, metadagger; metadagger.pin_cpu_kernels(); from metadagger.cli.bench_lanes import {child}"
    done = subprocess.run(
        [sys.executable, "-c", code + f"; {child}(sys.argv[1:])", str(run), str(seed), str(width), *overrides],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise UserError(f"the benchmark seed at width {width} failed: {done.stderr.strip()[-500:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _one_seed(argv: list[str]) -> tuple[Callable[[], str], Any]:
    """From RUN SEED WIDTH [OVERRIDE ...]: a function that runs that benchmark seed here (the inline
    executor, one torch thread, on a scratch copy sharing the run's pi*, pairs and mappers) and
    returns the rows' digest; and the run's task."""
    import torch

    from metadagger.pipeline.stages import load_run, stage_benchmark
    from metadagger.runfolder.driver import StageOptions
    from metadagger.tasks import make_task

    torch.set_num_threads(1)  # as in every worker
    run, seed, width, overrides = argv[0], int(argv[1]), int(argv[2]), argv[3:]
    config = load_run(run, overrides)
    config = dataclasses.replace(config, benchmark=dataclasses.replace(config.benchmark, seeds=(seed,), lanes=width))
    source = RunLayout(run)

    def benchmark_seed() -> str:
        with tempfile.TemporaryDirectory(prefix="metadagger-bench-") as tmp:
            scratch = RunLayout(tmp)
            for name in ("pistar", "pairs", "mappers"):  # read only: the mappers are checked against the pairs
                if (source.root / name).exists():
                    (scratch.root / name).symlink_to((source.root / name).resolve())
            stage_benchmark(scratch, config, options=StageOptions(executor="inline", progress=False))
            return hashlib.sha256(scratch.benchmark_table.read_bytes()).hexdigest()

    return benchmark_seed, make_task(config.task, **config.task_kwargs)


def lanes_child(argv: list[str]) -> None:
    """``bench lanes``' measurement of one width, in a process of its own: RUN SEED WIDTH [OVERRIDE ...].

    The seed runs in this process, so its CPU time and peak memory are this process's; prints them
    as one JSON line.
    """
    import resource

    benchmark_seed, _ = _one_seed(argv)
    wall, cpu = time.perf_counter(), time.process_time()
    digest = benchmark_seed()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    result = {
        "wall_seconds": wall,
        "worker_cpu_seconds": cpu,
        "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "rows_sha256": digest,
    }
    print(json.dumps(result))


def step_child(argv: list[str]) -> None:
    """``bench step``'s measurement, in a process of its own: RUN SEED WIDTH [OVERRIDE ...]. Times
    each part of a laned step by wrapping the function that does it; prints the seconds of each,
    the env steps and the wall seconds as one JSON line."""
    from metadagger.imitation import lanes
    from metadagger.tasks.base import LearnerEnv

    benchmark_seed, task = _one_seed(argv)
    probe = task.make_env()
    base = type(probe.unwrapped)
    probe.close()
    parts = ("lanes_step", "env_step", "expert_labels", "trunk_forward", "head_fits")
    # outside Lanes.step, the expert's labels are a reset's and the env's steps another rollout's
    elsewhere = {"expert_labels": "expert_labels_at_reset", "env_step": "env_step_outside_lanes"}
    seconds = dict.fromkeys(parts + tuple(elsewhere.values()), 0.0)
    # trunk_rows: the rows the trunk computed, the live lanes' and the padding to a checked shape
    counts = {"env_steps": 0, "trunk_forwards": 0, "trunk_rows": 0}
    stepping = [False]  # inside Lanes.step

    def timed(part: str, fn: Callable[..., Any], count: str | None = None) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            start, outer = time.perf_counter(), stepping[0]
            stepping[0] = outer or part == "lanes_step"
            try:
                return fn(*args, **kwargs)
            finally:
                stepping[0] = outer
                inside = outer or part not in elsewhere
                seconds[part if inside else elsewhere[part]] += time.perf_counter() - start
                if count is not None and inside:
                    counts[count] += 1

        return wrapper

    made = lanes.Lanes.__init__

    def lanes_init(self: Any, *args: Any, **kwargs: Any) -> None:
        made(self, *args, **kwargs)
        trunk = timed("trunk_forward", self._trunk, "trunk_forwards")

        def counted(batch: Any) -> Any:
            counts["trunk_rows"] += len(batch)
            return trunk(batch)

        self._trunk = counted

    lanes.Lanes.__init__ = lanes_init
    lanes.Lanes.step = timed("lanes_step", lanes.Lanes.step)
    lanes.fit_heads = timed("head_fits", lanes.fit_heads)
    base.step = timed("env_step", base.step, "env_steps")
    LearnerEnv._label_info = timed("expert_labels", LearnerEnv._label_info)
    wall = time.perf_counter()
    benchmark_seed()
    print(json.dumps({"wall_seconds": time.perf_counter() - wall, "seconds": seconds, **counts}))
