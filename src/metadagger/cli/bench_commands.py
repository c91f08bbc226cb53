"""``metadagger bench ...``: the speed benchmarks (:mod:`metadagger.cli.bench`), each writing JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Optional

import typer

from metadagger.cli.options import OUT, SET, TASK, user_errors

#: The seed ``bench lanes`` and ``bench step`` time.
TIMED_SEED = typer.Option(
    None,
    "--seed",
    help="The seed to time (default: the first seed above every seed the run names, so that no evaluation seed "
    "is rolled out to choose a width).",
)

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks that write JSON.")


def _measure_and_write(
    out: Path,
    flag: str,
    measure: Callable[[], dict],
    shown: Callable[[str, Any], bool] = lambda key, value: key != "machine",
) -> None:
    """Check ``out`` (given as ``flag``) before any work, run ``measure``, write its JSON to ``out``
    and echo the items ``shown`` keeps (by default all but the machine description)."""
    from metadagger.cli.bench import write_bench
    from metadagger.utils.io import check_output_file

    check_output_file(out, flag)
    result = measure()
    write_bench(result, out)
    typer.echo(json.dumps({k: v for k, v in result.items() if shown(k, v)}, indent=2))
    typer.echo(f"wrote {out}")


@bench_app.command("env")
@user_errors
def bench_env_cmd(
    task: str = TASK,
    seeds: str = typer.Option("0-2", "--seeds", help="Seeds to step."),
    steps: int = typer.Option(
        1000, "--steps", min=1, help="Steps per seed (1000: a full episode, as upstream registers it)."
    ),
    out: Path = typer.Option(Path("runs/bench/env.json"), "--out", help="JSON file to write."),
) -> None:
    """Steps per second of our env against upstream's, on the same seeds and actions."""
    from metadagger.cli.bench_env import bench_env
    from metadagger.utils.yaml_config import parse_seeds

    _measure_and_write(
        out,
        "--out",
        lambda: bench_env(task, seeds=parse_seeds(seeds), steps=steps),
        shown=lambda key, value: not isinstance(value, (dict, list)),
    )


@bench_app.command("bc")
@user_errors
def bench_bc_cmd(
    images: int = typer.Option(2000, "--images", min=10, help="Random 96x96x3 images to fit on."),
    epochs: int = typer.Option(3, "--epochs", min=1, help="Epochs of each fit."),
    out: Path = typer.Option(Path("runs/bench/bc.json"), "--out", help="JSON file to write."),
) -> None:
    """Full BC fit vs head-only refit on cached trunk features, and inference latency."""
    from metadagger.cli.bench import bench_bc

    _measure_and_write(out, "--out", lambda: bench_bc(images=images, epochs=epochs))


@bench_app.command("fit")
@user_errors
def bench_fit_cmd(
    task: str = typer.Option("fetch", "--task", help="Task whose pi* network and preset fit are timed."),
    preset: str = typer.Option("paper", "--preset", help="Preset whose pistar.bc settings are used."),
    steps: int = typer.Option(200, "--steps", min=1, help="Adam steps timed on each device."),
    shards: list[int] = typer.Option(
        [], "--shards", min=1, help="Also time the CPU fit at this batch_shards (repeat it: --shards 1 --shards 2)."
    ),
    out: Path = typer.Option(Path("runs/bench/fit.json"), "--out", help="JSON file to write."),
) -> None:
    """pi*'s whole-network fit: seconds per Adam step on the CPU and, where there is one, on the GPU.

    With --shards, the CPU's step again at each batch_shards; always, the share of a CPU step spent
    in the convolutions' forward and backward kernels."""
    from metadagger.cli.bench import bench_fit

    _measure_and_write(out, "--out", lambda: bench_fit(task, preset=preset, steps=steps, shards=shards))


@bench_app.command("prior")
@user_errors
def bench_prior_cmd(
    fits: int = typer.Option(32, "--fits", min=1, help="Fits batched together (also timed: one alone)."),
    rows: int = typer.Option(500, "--rows", min=10, help="Feature rows each fit learns from."),
    epochs: int = typer.Option(20, "--epochs", min=1, help="Epochs of each fit."),
    repeats: int = typer.Option(3, "--repeats", min=1, help="Alternating timings of each; the best is kept."),
    out: Path = typer.Option(Path("runs/bench/prior.json"), "--out", help="JSON file to write."),
) -> None:
    """A head-only fit with a Gaussian prior against the same fit without: seconds and their ratio."""
    from metadagger.cli.bench import bench_prior

    _measure_and_write(out, "--out", lambda: bench_prior(fits=fits, rows=rows, epochs=epochs, repeats=repeats))


@bench_app.command("pairs")
@user_errors
def bench_pairs_cmd(
    out: Path = OUT,
    seeds: int = typer.Option(4, "--seeds", help="How many of the run's pair seeds to time."),
    json_out: Path = typer.Option(Path("runs/bench/pairs.json"), "--json", help="JSON file to write."),
    target_kept: int = typer.Option(
        375, "--target-kept", help="Kept pairs to extrapolate the time for (the paper's: 375)."
    ),
    nodes: list[int] = typer.Option(
        [4, 16], "--nodes", help="Ray cluster sizes to extrapolate to (nodes like this machine); repeatable."
    ),
    lanes: list[int] = typer.Option(
        [], "--lanes", help="Also time pairs.lanes at this width, with 2 workers, side by side; repeatable."
    ),
) -> None:
    """Seconds per pair with 1 and 2 workers, and pairs per hour.

    Also the hours for --target-kept kept pairs here and (extrapolated) on Ray clusters of --nodes nodes."""
    from metadagger.cli.bench import bench_pairs

    _measure_and_write(
        json_out,
        "--json",
        lambda: bench_pairs(out, seeds=seeds, target_kept=target_kept, nodes=nodes, lanes=tuple(lanes)),
    )


@bench_app.command("lanes")
@user_errors
def bench_lanes_cmd(
    out: Path = OUT,
    seed: Optional[int] = TIMED_SEED,
    lanes: list[int] = typer.Option([1, 32], "--lanes", help="Lane widths to time, side by side; repeatable."),
    repeats: int = typer.Option(1, "--repeats", help="Times each width is measured, the widths taking turns."),
    overrides: list[str] = SET,
    json_out: Path = typer.Option(Path("runs/bench/lanes.json"), "--json", help="JSON file to write."),
) -> None:
    """One benchmark seed of a run at each lane width: wall and CPU seconds, peak memory, speed-ups."""
    from metadagger.cli.bench_lanes import bench_lanes

    _measure_and_write(
        json_out,
        "--json",
        lambda: bench_lanes(out, seed=seed, widths=tuple(lanes), overrides=tuple(overrides), repeats=repeats),
    )


@bench_app.command("step")
@user_errors
def bench_step_cmd(
    out: Path = OUT,
    seed: Optional[int] = TIMED_SEED,
    lanes: Optional[int] = typer.Option(None, "--lanes", help="The lane width (default: the run's benchmark.lanes)."),
    overrides: list[str] = SET,
    json_out: Path = typer.Option(Path("runs/bench/step.json"), "--json", help="JSON file to write."),
) -> None:
    """Where a laned benchmark step's time goes, and a step's time over the env's own.

    Per env step: the env's own step, the expert's labels, pi*'s trunk and the rest."""
    from metadagger.cli.bench_lanes import bench_step

    _measure_and_write(json_out, "--json", lambda: bench_step(out, seed=seed, width=lanes, overrides=tuple(overrides)))


@bench_app.command("reproduce")
@user_errors
def bench_reproduce_cmd(
    task: str = TASK,
    preset: str = typer.Option("quick", "--preset", help="The built-in preset whose whole runs are timed."),
    overrides: list[str] = SET,
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="Workers of both runs (default: all cores)."),
    out: Path = typer.Option(Path("runs/bench/reproduce.json"), "--out", help="JSON file to write."),
) -> None:
    """Whole runs of --preset as it is and with the --set overrides (e.g. lane widths), one after the other.

    Seconds per stage, the speed-up, peak memory and whether the tables agree."""
    from metadagger.cli.bench_reproduce import bench_reproduce

    _measure_and_write(
        out, "--out", lambda: bench_reproduce(task, preset=preset, overrides=tuple(overrides), workers=workers)
    )


@bench_app.command("kernels")
@user_errors
def bench_kernels_cmd(
    task: str = TASK,
    preset: str = typer.Option("ci", "--preset", help="The built-in preset whole runs of which are timed."),
    repeats: int = typer.Option(2, "--repeats", min=1, help="Runs on each kind of kernels, alternated."),
    out: Path = typer.Option(Path("runs/bench/kernels.json"), "--out", help="JSON file to write."),
) -> None:
    """What the CPU kernel pins cost: whole runs of --preset on the pinned kernels and on this machine's own.

    Side by side, and whether the two give the same numbers."""
    from metadagger.cli.bench import bench_kernels

    _measure_and_write(out, "--out", lambda: bench_kernels(task, preset=preset, repeats=repeats))


@bench_app.command("ops")
@user_errors
def bench_ops_cmd(
    out: Path = typer.Option(Path("runs/bench/ops.json"), "--out", help="JSON file to write."),
    compare: Optional[Path] = typer.Option(
        None, "--compare", help="Another machine's fingerprint (its --out) to compare with."
    ),
) -> None:
    """A fingerprint of every kind of computation a run does: sha256 of each output on fixed inputs.

    With --compare, the computations whose bits differ on the other machine, first one first."""
    from metadagger.cli.fingerprint import compare_fingerprints, fingerprint_kernels, read_fingerprint

    other = read_fingerprint(compare) if compare is not None else None

    def measure() -> dict:
        mine = fingerprint_kernels()
        return {**mine, "compared": compare_fingerprints(mine, other)} if other is not None else mine

    _measure_and_write(out, "--out", measure, shown=lambda key, value: key in ("compared", "machine"))


@bench_app.command("numerics")
@user_errors
def bench_numerics_cmd(
    out: Path = OUT,
    lanes: int = typer.Option(32, "--lanes", help="The lane width whose batched forwards are compared with batch 1."),
    states: int = typer.Option(100_000, "--states", help="How many of pi*'s states to compare (whole episodes)."),
    first_seed: int = typer.Option(30000, "--first-seed", help="The first of the episode seeds (then one up)."),
    json_out: Path = typer.Option(Path("runs/bench/numerics.json"), "--json", help="JSON file to write."),
) -> None:
    """pi*'s actions at batch 1 and in lanes: the share of states whose action the lanes change."""
    from metadagger.cli.bench_numerics import bench_numerics

    _measure_and_write(
        json_out, "--json", lambda: bench_numerics(out, width=lanes, states=states, first_seed=first_seed)
    )
