"""Where a pair's seconds go: each part of the pair procedure timed on a run's pi*.

usage: python scripts/profile_pair.py RUN SEEDS     e.g. python scripts/profile_pair.py runs/quick 1000-1003

One process, one torch thread. The first seed warms up (TorchScript's compile, oneDNN's
primitives) and is not counted; the others are made with `run_pair`, exactly as `metadagger pairs`
makes them, with a clock around each call of the parts below. Prints JSON: seconds per pair and
calls per pair of each part, the rest, and the process's CPU seconds per pair beside its wall
seconds (more CPU than wall means threads beside the main one were busy).
"""

from __future__ import annotations

import functools
import json
import sys
import time
from collections import Counter
from typing import Any, Callable

import torch

from metadagger.imitation.bc import FeatureCache
from metadagger.imitation.head_adam import LinearHeadAdam
from metadagger.metal_dagger.pairs import run_pair
from metadagger.pipeline.stages import load_run, run_task
from metadagger.policies import Policy
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks.base import LearnerEnv
from metadagger.utils.yaml_config import parse_seeds

#: (owner, method, what the docs call it)
PARTS = (
    (Policy, "__call__", "learner forwards (trunk and head, batch 1)"),
    (LearnerEnv, "step", "environment steps (physics, renderer, expert's label)"),
    (LinearHeadAdam, "steps", "head-only Adam steps"),
    (FeatureCache, "_row_indices", "trunk features of fitted states (hashing, batches of 256)"),
)


def _timed(method: Callable[..., Any], name: str, seconds: Counter, calls: Counter) -> Callable[..., Any]:
    @functools.wraps(method)
    def timed(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds[name] += time.perf_counter() - start
            calls[name] += 1

    return timed


def main(run: str, seeds: str) -> dict[str, Any]:
    """Time the pairs of ``seeds`` (the first one warms up) on the pi* of ``run``."""
    torch.set_num_threads(1)
    warm_up, *timed_seeds = parse_seeds(seeds)
    if not timed_seeds:
        raise SystemExit("give at least two seeds: the first one warms up")
    config = load_run(run)
    task, pistar = run_task(config), str(RunLayout(run).pistar)
    seconds: Counter = Counter()
    calls: Counter = Counter()
    for owner, method, name in PARTS:
        setattr(owner, method, _timed(getattr(owner, method), name, seconds, calls))
    run_pair(task, pistar, warm_up, config.pairs)
    seconds.clear()
    calls.clear()
    wall, cpu = time.perf_counter(), time.process_time()
    for seed in timed_seeds:
        run_pair(task, pistar, seed, config.pairs)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n = len(timed_seeds)
    parts = {name: {"seconds_per_pair": seconds[name] / n, "calls_per_pair": calls[name] / n} for _, _, name in PARTS}
    return {
        "run": run,
        "seeds": timed_seeds,
        "wall_seconds_per_pair": wall / n,
        "cpu_seconds_per_pair": cpu / n,
        "parts": parts,
        "rest_seconds_per_pair": (wall - sum(seconds.values())) / n,
    }


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    print(json.dumps(main(sys.argv[1], sys.argv[2]), indent=2))
