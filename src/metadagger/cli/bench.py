"""Benchmarks that write JSON: ``bench_bc`` times a full BC fit against a head refit, ``bench_fit``
pi*'s whole-network fit, ``bench_prior`` the head fits with a prior, ``bench_pairs`` the pair stage,
``bench_kernels`` the kernel pins (``bench env`` is :mod:`metadagger.cli.bench_env`, ``bench lanes``
:mod:`metadagger.cli.bench_lanes`)."""

from __future__ import annotations

import hashlib
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.machine_cache import CACHE_ENV, OFF
from metadagger.utils.io import read_json, write_json
from metadagger.utils.kernels import KERNEL_ENV, NATIVE_SWITCH, machine_description


def write_bench(result: dict, path: str | Path) -> Path:
    """Write a benchmark result as JSON, atomically; returns the path."""
    return write_json(path, result)


def machine_block() -> dict[str, Any]:
    """The machine a benchmark ran on: platform, library versions, load, and the CPU and kernels in effect."""
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "gymnasium": gym.__version__,
        "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "cpu": machine_description(),
    }


def bench_pairs(
    run: str | Path,
    *,
    seeds: int = 4,
    workers: Sequence[int] = (1, 2),
    target_kept: int = 375,
    nodes: Sequence[int] = (4, 16),
    lanes: Sequence[int] = (),
) -> dict:
    """Time pair collection with 1 and 2 workers on the first ``seeds`` pair seeds of a run, one
    seed at a time (``pairs.lanes`` 1, whatever the run sets).

    With ``lanes``, the same seeds are also made at each of those ``pairs.lanes`` widths with the
    most workers, side by side: ``lanes`` holds their seconds and pairs per hour, and
    ``lanes_speedup`` each width's pairs per hour over width 1's with as many workers. Each width
    needs seeds for blocks at least half as wide (``block_sizes``: the blocks the stage cut), or
    the ratio would time idle lanes.

    Each measurement collects into a fresh temporary store (process-pool start-up included), so
    the run's own pairs are untouched. The kept share comes from the run's ``pairs/summary.json``
    when the run has one, else from the bench's own seeds; with it the bench extrapolates the
    minutes needed for ``target_kept`` kept pairs (default the paper's 300 train + 75 validation)
    at the fastest rate measured with the most workers on this machine, and on Ray clusters of
    ``nodes`` nodes like it (``extrapolated``: pair seeds are independent jobs, so the rate is
    taken to grow with the node count; measured on one machine only).
    """
    import dataclasses
    import tempfile

    from metadagger.imitation.lanes import check_lanes
    from metadagger.metal_dagger.lane_blocks import block_sizes
    from metadagger.metal_dagger.pairs import collect_pairs
    from metadagger.metal_dagger.pistar import load_pistar
    from metadagger.pipeline.run_config import load_run
    from metadagger.pipeline.stage_inputs import run_task
    from metadagger.runfolder.driver import StageOptions

    run = Path(run)
    layout = RunLayout(run)
    config = load_run(run)
    for width in lanes:
        check_lanes("bench pairs --lanes", width)
    if target_kept < 1 or any(n < 1 for n in nodes):
        raise UserError(f"bench pairs needs --target-kept >= 1 and --nodes >= 1, got {target_kept} and {list(nodes)}")
    if seeds < 1 or len(config.pairs.seeds) < seeds:
        raise UserError(
            f"bench pairs needs 1 <= --seeds <= {len(config.pairs.seeds)} (the run's pair seeds), got {seeds}"
        )
    blocks = {str(w): block_sizes(seeds, w, max(workers)) for w in lanes}
    for width in lanes:  # blocks under half the width time the lanes' idle rows, not the lanes
        if 2 * min(blocks[str(width)]) < width:
            raise UserError(
                f"bench pairs --lanes {width} cuts --seeds {seeds} into blocks of {min(blocks[str(width)])} lanes "
                f"for {max(workers)} workers, under half the width; give --seeds {max(workers) * width} for full blocks"
            )
    load_pistar(layout)  # a missing or corrupt pi* is named under its own path, not the scratch copies'
    run_summary = layout.pairs_summary
    run_kept = read_json(run_summary, "the run's pairs summary") if run_summary.is_file() else None
    pairs_config = dataclasses.replace(config.pairs, seeds=tuple(config.pairs.seeds[:seeds]), lanes=1)
    task = run_task(config)

    def timed(config: Any, n: int) -> tuple[float, dict]:
        # into a scratch run that shares the run's pi*; process-pool start-up included
        with tempfile.TemporaryDirectory(prefix="metadagger-bench-") as tmp:
            scratch = RunLayout(tmp)
            scratch.pistar_dir.mkdir()
            scratch.pistar.symlink_to(layout.pistar.resolve())
            start = time.perf_counter()
            made = collect_pairs(task, scratch, config, StageOptions(workers=n, progress=False))
            return time.perf_counter() - start, made

    timings: dict[str, float] = {}
    summary: dict = {}
    for n in workers:
        timings[str(n)], summary = timed(pairs_config, n)
    by_width = {str(w): timed(dataclasses.replace(pairs_config, lanes=w), max(workers))[0] for w in lanes}
    kept_source = summary if run_kept is None else run_kept
    kept_share = kept_source["kept"] / kept_source["seeds"] if kept_source["seeds"] else 0.0
    best = str(max(workers))
    pairs_per_hour = 3600.0 * seeds / min([timings[best], *by_width.values()])
    minutes = (60.0 * target_kept / (kept_share * pairs_per_hour)) if kept_share > 0 else None
    return {
        "run": str(run),
        "seeds": seeds,
        "run_pairs_lanes": config.pairs.lanes,
        "seconds": timings,
        "seconds_per_pair": {k: v / seeds for k, v in timings.items()},
        "pairs_per_hour": {k: 3600.0 * seeds / v for k, v in timings.items()},
        "speedup": {k: timings[str(min(workers))] / v for k, v in timings.items()},
        "lanes": {
            k: {"workers": max(workers), "block_sizes": blocks[k], "seconds": v, "pairs_per_hour": 3600.0 * seeds / v}
            for k, v in by_width.items()
        },
        "lanes_speedup": {k: timings[best] / v for k, v in by_width.items()},
        "kept_share": kept_share,
        "kept_share_from": "bench" if run_kept is None else "run",
        "target_kept": target_kept,
        "minutes_for_target_kept": minutes,
        "extrapolated": {
            "assumes": f"a Ray cluster of N nodes like this machine, each running {best} workers, collects "
            "N times this machine's pairs per hour (not measured)",
            "pair_seeds_for_target_kept": math.ceil(target_kept / kept_share) if kept_share > 0 else None,
            "hours_on_ray_nodes": {str(n): None if minutes is None else minutes / 60.0 / n for n in (1, *nodes)},
        },
        "machine": machine_block(),
    }


def bench_bc(*, images: int = 2000, epochs: int = 3, seed: int = 0) -> dict:
    """Full BC fit vs head-only refit (trunk frozen, features cached) on the same random
    96x96x3 images and 20-class labels: seconds and speed-ups, plus batch-1 inference latency."""
    from metadagger.imitation.bc import BCConfig, fit_bc
    from metadagger.imitation.data import Dataset
    from metadagger.imitation.features import FeatureCache
    from metadagger.policies import Policy, PolicyNet

    def fresh() -> Policy:
        net = PolicyNet(obs_shape=(96, 96, 3), n_outputs=20, discrete=True)
        net.init_weights(seed)
        return Policy(net=net, task="carracing")

    rng = np.random.default_rng(seed)
    data = Dataset(
        obs=rng.integers(0, 256, (images, 96, 96, 3), dtype=np.uint8),
        labels=rng.integers(0, 20, images).astype(np.int64),
    )
    full_s = fit_bc(fresh(), data, BCConfig(epochs=epochs, seed=seed))["seconds"]
    policy = fresh()
    cache = FeatureCache(policy)
    start = time.perf_counter()
    cache.features(data.obs)
    features_s = time.perf_counter() - start
    head_s = fit_bc(policy, data, BCConfig(epochs=epochs, head_only=True, seed=seed), cache=cache)["seconds"]
    obs = data.obs[0]
    for _ in range(50):
        policy(obs)
    start = time.perf_counter()
    for _ in range(500):
        policy(obs)
    return {
        "images": images,
        "epochs": epochs,
        "parameters": sum(p.numel() for p in policy.net.parameters()),
        "head_size": policy.head_size,
        "full_fit_s": full_s,
        "head_only_features_s": features_s,
        "head_only_fit_s": head_s,
        "speedup_incl_features": full_s / (features_s + head_s),
        "speedup_cached_refit": full_s / head_s,
        "inference_ms_batch1": 1000 * (time.perf_counter() - start) / 500,
        "machine": machine_block(),
    }


def _fit_part(op: str) -> str:
    """The part of a whole-network fit a profiled op belongs to: the convolutions' forward or
    backward kernels (oneDNN's or ATen's own), or the rest."""
    name = op.lower()  # autograd's nodes are named "ConvolutionBackward0"
    if "conv" not in name:
        return "rest"
    return "convolutions_backward" if "backward" in name else "convolutions_forward"


def fit_time_shares(fit: Callable[[], object]) -> dict[str, float]:
    """Where a whole-network fit's CPU time goes: the share of its ops' own CPU time spent in the
    convolutions' forward kernels, in their backward kernels (weights' and inputs' gradients) and
    in everything else (the other layers, the loss, Adam, gathering the batch)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as profiled:
        fit()
    seconds = dict.fromkeys(("convolutions_forward", "convolutions_backward", "rest"), 0.0)
    for event in profiled.key_averages():
        seconds[_fit_part(event.key)] += event.self_cpu_time_total
    total = sum(seconds.values())
    return {part: value / total for part, value in seconds.items()}


def bench_fit(
    task_name: str = "fetch",
    *,
    preset: str = "paper",
    steps: int = 200,
    shards: Sequence[int] = (),
    seed: int = 0,
) -> dict:
    """pi*'s whole-network fit (the preset's ``pistar.bc``: network, batch, augmentation,
    Adam) for ``steps`` Adam steps on random frames of the task's shape: seconds per step on the
    CPU (one thread, as a stage computes) and, where torch sees a GPU, on it, side by side; the
    CPU's seconds again at each of ``shards`` (``batch_shards``: threads that split a batch's
    gradient, another sum and so another pi*), and where a CPU step's time goes
    (:func:`fit_time_shares`, on at most 20 steps)."""
    import dataclasses

    import torch

    from metadagger.imitation.bc import fit_bc
    from metadagger.imitation.data import Dataset
    from metadagger.pipeline.run_config import resolve_config
    from metadagger.policies import make_policy
    from metadagger.tasks import make_task
    from metadagger.utils.device import current_device, use_device

    for count in shards:
        if not isinstance(count, int) or count < 1:
            raise UserError(f"--shards must be integers >= 1, got {count!r}; e.g. --shards 1 --shards 2")
    task = make_task(task_name)
    bc = dataclasses.replace(resolve_config(task_name, preset).pistar.bc, epochs=1, seed=seed)
    shape = tuple(make_policy(task, seed=seed).arch["obs_shape"])
    rng = np.random.default_rng(seed)
    n = steps * bc.batch_size
    dim = task.label_dim()
    if task.is_discrete:
        labels = rng.integers(0, dim, n).astype(np.int64)
    else:
        labels = rng.standard_normal((n, dim)).astype(np.float32)
    data = Dataset(obs=rng.integers(0, 256, (n, *shape), dtype=np.uint8), labels=labels)
    warm_up = Dataset(obs=data.obs[: 2 * bc.batch_size], labels=labels[: 2 * bc.batch_size])
    profiled = Dataset(obs=data.obs[: 20 * bc.batch_size], labels=labels[: 20 * bc.batch_size])

    def seconds_per_step(device: str, batch_shards: int = bc.batch_shards) -> float:
        before = current_device()
        use_device(device)
        config = dataclasses.replace(bc, batch_shards=batch_shards)
        try:
            fit_bc(make_policy(task, seed=seed), warm_up, config)
            return fit_bc(make_policy(task, seed=seed), data, config)["seconds"] / steps
        finally:
            use_device(before)

    torch.set_num_threads(1)
    result: dict[str, Any] = {
        "task": task_name,
        "preset": preset,
        "steps": steps,
        "batch_size": bc.batch_size,
        "batch_shards": bc.batch_shards,
    }
    result["cpu_s_per_step"] = seconds_per_step("cpu")
    if shards:
        at = {  # the preset's own count is the step timed above
            str(count): result["cpu_s_per_step"] if count == bc.batch_shards else seconds_per_step("cpu", count)
            for count in sorted(set(shards))
        }
        result["cpu_s_per_step_at_shards"] = at
        result["speedup_over_fewest_shards"] = {count: at[min(at, key=int)] / value for count, value in at.items()}
    result["cpu_time_shares"] = fit_time_shares(
        lambda: fit_bc(make_policy(task, seed=seed), profiled, dataclasses.replace(bc, batch_shards=1))
    )
    if torch.cuda.is_available():
        result["gpu"] = torch.cuda.get_device_name(0)
        result["gpu_s_per_step"] = seconds_per_step("cuda")
        result["gpu_speedup"] = result["cpu_s_per_step"] / result["gpu_s_per_step"]
    result["machine"] = machine_block()
    return result


def bench_prior(*, fits: int = 32, rows: int = 500, epochs: int = 20, repeats: int = 3, seed: int = 0) -> dict:
    """Batched head-only fits with and without a Gaussian prior on the same data (CarRacing's
    head: 20 classes on 64 features), timed alternately ``repeats`` times: the prior's cost as a
    ratio, for one fit alone and for ``fits`` fits batched."""
    import torch

    from metadagger.imitation.head_fits import HeadFit, Prior, fit_heads

    torch.set_num_threads(1)
    generator = torch.Generator().manual_seed(seed)
    out_dim, dim = 20, 64
    size = out_dim * (dim + 1)

    def request(k: int, prior: bool) -> HeadFit:
        return HeadFit(
            head=torch.randn(size, generator=torch.Generator().manual_seed(k)) * 0.1,
            features=torch.rand(rows, dim, generator=torch.Generator().manual_seed(1000 + k)),
            targets=torch.randint(0, out_dim, (rows,), generator=torch.Generator().manual_seed(2000 + k)),
            orders=torch.stack([torch.randperm(rows, generator=generator) for _ in range(epochs)]),
            lr=1e-3,
            weight_decay=0.0,
            batch_size=10,
            called=f"bench fit {k}",
            prior=Prior(mean=torch.zeros(size), weight=torch.full((size,), 1e-3)) if prior else None,
        )

    result: dict[str, Any] = {"rows": rows, "epochs": epochs, "repeats": repeats, "head_size": size}
    for count in (1, fits):
        plain, priored = [request(k, False) for k in range(count)], [request(k, True) for k in range(count)]
        fit_heads(plain, out_dim=out_dim, discrete=True)  # compiles the kernel; warms the caches
        seconds: dict[str, list[float]] = {"plain": [], "prior": []}
        for _ in range(repeats):
            for name, batch in (("plain", plain), ("prior", priored)):
                start = time.perf_counter()
                fit_heads(batch, out_dim=out_dim, discrete=True)
                seconds[name].append(time.perf_counter() - start)
        best = {name: min(values) for name, values in seconds.items()}
        result[f"fits_{count}"] = {
            "plain_s": best["plain"],
            "prior_s": best["prior"],
            "prior_over_plain": best["prior"] / best["plain"],
        }
    return result


def _kernel_environment(kernels: str) -> dict[str, str]:
    """This process's environment without any kernel setting, plus ``native``'s switch, and the
    machine's cache off (each repeat trains its own pi*)."""
    env = {k: v for k, v in os.environ.items() if k not in KERNEL_ENV and k != NATIVE_SWITCH}
    env[CACHE_ENV] = OFF
    return {**env, NATIVE_SWITCH: "native"} if kernels == "native" else env


def bench_kernels(task: str = "carracing", *, preset: str = "ci", repeats: int = 2, progress: bool = True) -> dict:
    """The cost of the kernel pins: one whole ``reproduce`` of ``preset``, in fresh processes, on
    the pinned kernels and on the machine's own (``METADAGGER_KERNELS=native``), alternated
    ``repeats`` times so both share the machine's load; median seconds, their ratio, and whether
    the two give the same ``eval/mdm.csv``."""
    seconds: dict[str, list[float]] = {"pinned": [], "native": []}
    digests: dict[str, set[str]] = {"pinned": set(), "native": set()}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for kernels in ("pinned", "native") if r % 2 == 0 else ("native", "pinned"):
                out = Path(tmp) / f"{kernels}-{r}"
                command = [
                    sys.executable,
                    "-m",
                    "metadagger.cli",
                    "reproduce",
                    "--task",
                    task,
                    "--preset",
                    preset,
                    "--out",
                    str(out),
                ]
                start = time.perf_counter()
                done = subprocess.run(command, env=_kernel_environment(kernels), capture_output=True, text=True)
                if done.returncode != 0:
                    raise RuntimeError(f"reproduce on {kernels} kernels failed: {done.stderr.strip()[-2000:]}")
                seconds[kernels].append(time.perf_counter() - start)
                digests[kernels].add(hashlib.sha256((out / "eval" / "mdm.csv").read_bytes()).hexdigest())
                if progress:
                    print(f"{kernels} kernels, repeat {r + 1}/{repeats}: {seconds[kernels][-1]:.1f} s", file=sys.stderr)
    median = {k: statistics.median(v) for k, v in seconds.items()}
    return {
        "task": task,
        "preset": preset,
        "repeats": repeats,
        "seconds": seconds,
        "median_s": median,
        "pinned_over_native": median["pinned"] / median["native"],
        "mdm_csv_sha256": {k: sorted(v) for k, v in digests.items()},
        "same_numbers": digests["pinned"] == digests["native"],
        "machine": machine_block(),
    }
