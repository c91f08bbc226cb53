"""The ``metadagger`` command line: thin wrappers that build a config and call the library.

A :class:`~metadagger.errors.UserError` becomes one ``error: ...`` line on stderr and exit code 2
(:func:`~metadagger.cli.options.user_errors`, beside the options every command shares); the
process around the commands (usage errors, signals, exit codes) is :mod:`metadagger.cli.entry`;
the ``bench`` commands are :mod:`metadagger.cli.bench_commands`, the ``results`` ones
:mod:`metadagger.cli.results_commands`, the ``config`` ones :mod:`metadagger.cli.config_commands`, and
``demo``, ``expert`` and ``check-task`` :mod:`metadagger.cli.task_commands`, and ``label``
:mod:`metadagger.cli.label_command`.

The command line runs on pinned CPU kernels (:func:`~metadagger.utils.kernels.pin_cpu_kernels`):
:func:`metadagger.cli.entry.main` pins them first thing, and this module pins them before its one import of
torch-using code (the mapper kinds named in ``--kind``'s help); the commands import the rest of
the library when they run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from metadagger.errors import UserError
from metadagger.utils.kernels import pin_cpu_kernels

pin_cpu_kernels()  # before the registry below loads torch, and before any command's tensor operation

from metadagger.cli.bench_commands import bench_app
from metadagger.cli.config_commands import config_app
from metadagger.cli.label_command import label_app
from metadagger.cli.options import (
    ADDRESS,
    DEVICE,
    EXECUTOR,
    OUT,
    PRESET,
    PRESETS_FILE,
    REBUILD,
    SET,
    TASK,
    WORKERS,
    listed,
    stage_options,
    user_errors,
)
from metadagger.cli.results_commands import results_app
from metadagger.cli.task_commands import task_app
from metadagger.evaluation.benchmark.methods import benchmark_methods
from metadagger.mapping.registry import kind_names, trained_names

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Meta-Learning DAgger: imitation learning that maps BC weights to DAgger weights.",
)
app.add_typer(bench_app, name="bench")
app.add_typer(results_app, name="results")
app.add_typer(task_app)
app.add_typer(config_app, name="config")
app.add_typer(label_app)


@app.callback()
def _setup() -> None:
    """Meta-Learning DAgger: imitation learning that maps BC weights to DAgger weights."""
    import torch

    # one thread everywhere (driver and workers): the same config and seeds give the same
    # weights on any machine, whatever its core count
    torch.set_num_threads(1)


@app.command()
@user_errors
def pistar(
    task: str = TASK,
    preset: str = PRESET,
    out: Path = OUT,
    presets: Optional[Path] = PRESETS_FILE,
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    device: Optional[str] = DEVICE,
) -> None:
    """Train pi*: BC on expert demos of K seeds, then DAgger rounds over all of them."""
    from metadagger.metal_dagger.pistar import pistar_rates
    from metadagger.pipeline.stages import init_run, stage_pistar
    from metadagger.runfolder.driver import StageOptions
    from metadagger.runfolder.layout import RunLayout

    layout = RunLayout(out)
    config = init_run(out, task, preset, presets, overrides, device)
    metrics = stage_pistar(layout, config, StageOptions(rebuild=rebuild))
    typer.echo(f"pi*: {pistar_rates(metrics)}")
    if metrics["unseen_seeds"]["success_rate"] < config.pistar.min_success:
        typer.echo(
            f"warning: pi* is below pistar.min_success={config.pistar.min_success:g} on its unseen seeds: "
            'the pairs stage will refuse it (docs/custom_task.md, "Making pi* work on a new task")',
            err=True,
        )
    if metrics.get("bc_selection"):
        choice = metrics["bc_selection"]
        typer.echo(
            f"pi* is epoch {choice['epoch']} of its BC fit: {choice['successes']}/{choice['episodes']} held-out seeds"
        )
    typer.echo(f"wrote {layout.pistar}")


@app.command()
@user_errors
def pairs(
    out: Path = OUT,
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Collect per-seed (w_BC, w_DA) pairs with pi*'s frozen trunk; resumes unfinished seeds."""
    from metadagger.pipeline.stages import load_run, stage_pairs
    from metadagger.runfolder.layout import RunLayout

    options = stage_options(rebuild, executor, workers, address)  # before any work
    layout = RunLayout(out)
    from metadagger.metal_dagger.pairs import negligible_change_warning

    summary = stage_pairs(layout, load_run(out, overrides), options)
    typer.echo(json.dumps(summary, indent=2))
    warning = negligible_change_warning(summary)
    if warning:
        typer.echo(warning, err=True)
    typer.echo(f"wrote {layout.pairs_dir}")


@app.command("train-mapper")
@user_errors
def train_mapper_cmd(
    out: Path = OUT,
    kind: str = typer.Option("all", "--kind", help=f"A mapper kind ({listed(kind_names)}) or all."),
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Train mappers on the run's kept pairs, one kind per worker.

    Each mapper's curves.csv and curves.png are written beside it."""
    from metadagger.pipeline.stages import load_run, stage_mappers
    from metadagger.runfolder.layout import RunLayout

    options = stage_options(rebuild, executor, workers, address)  # before any work
    kinds = kind_names() if kind == "all" else (kind,)
    for path in stage_mappers(RunLayout(out), load_run(out, overrides), kinds, options):
        typer.echo(f"wrote {path}")


@app.command()
@user_errors
def tune(
    out: Path = OUT,
    kind: str = typer.Option(
        ...,
        "--kind",
        help=f"The mapper kind to tune: {listed(trained_names)} (the kinds "
        "trained by Adam; ridge and the controls have nothing to tune).",
    ),
    trials: int = typer.Option(
        30,
        "--trials",
        help="Completed trials the study should hold in all; a resumed study runs only the missing ones.",
    ),
    seed: int = typer.Option(0, "--seed", help="Seeds the sampler (a trial's own seed is mappers.<kind>.seed)."),
    apply: bool = typer.Option(
        False,
        "--apply",
        help="Write the best settings into the run's config.yaml (mappers.<kind>), "
        "for train-mapper --rebuild and reproduce.",
    ),
    overrides: list[str] = SET,
    rebuild: bool = typer.Option(
        False,
        "--rebuild",
        help="Delete the kind's study and start a new one (a study resumes "
        "only with the pairs, split and untuned settings it was made from).",
    ),
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Search a mapper's hyperparameters with Optuna, on the run's pair seeds only.

    Trials train on the run's training pairs and are scored on its validation pairs (never on evaluation seeds); the
    study in tune/<kind>.db resumes, the best trial goes to tune/<kind>.yaml (docs/tuning.md)."""
    from metadagger.pipeline.stages import load_run, stage_tune
    from metadagger.runfolder.layout import RunLayout

    options = stage_options(rebuild, executor, workers, address)
    layout = RunLayout(out)
    result = stage_tune(layout, load_run(out, overrides), kind, trials=trials, seed=seed, apply=apply, options=options)
    baseline = "" if result.baseline_value is None else f" (trial 0, the run's settings: {result.baseline_value:.6g})"
    typer.echo(
        f"{kind}: best of {result.completed} trials is trial {result.best_trial}, validation MSE "
        f"{result.best_value:.6g}{baseline}; {result.ran} {'trial' if result.ran == 1 else 'trials'} ran now"
    )
    typer.echo(f"wrote {result.summary} (study: {result.study})")
    if apply:
        typer.echo(
            f"applied to {layout.config}; retrain with: metadagger train-mapper --out {out} --kind {kind} --rebuild"
        )
    else:
        typer.echo(f"use it with train-mapper --kind {kind} --rebuild, or reproduce: --set '{result.set_item}'")


PROTOCOLS = ("mdm", "mdi", "all")


@app.command()
@user_errors
def evaluate(
    out: Path = OUT,
    seeds: Optional[str] = typer.Option(
        None, "--seeds", help="Unseen seeds (default: the run's evaluate.seeds and mdi.seeds)."
    ),
    protocol: str = typer.Option(
        "all", "--protocol", help="mdm (MDM and one-shot), mdi (runs with an mdi section) or all."
    ),
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """MDM and one-shot evaluation of BC, every mapper and the controls on unseen seeds.

    Runs whose config has an mdi section also run the MDI protocol (DAgger-MDI vs DAgger-BC vs DAgger). Only the missing
    (seed, method) rows are evaluated."""
    from metadagger.pipeline.stages import load_run, stage_evaluate, stage_mdi
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.yaml_config import parse_seeds

    options = stage_options(rebuild, executor, workers, address)
    if protocol not in PROTOCOLS:
        raise UserError(f"unknown protocol {protocol!r}; expected {', '.join(PROTOCOLS)}")
    layout = RunLayout(out)
    config = load_run(out, overrides)
    if protocol == "mdi" and config.mdi is None:
        raise UserError(f"run {out} (task {config.task}) has no mdi section; use --protocol mdm")
    chosen = parse_seeds(seeds) if seeds is not None else None
    if protocol in ("mdm", "all"):
        rows = stage_evaluate(layout, config, seeds=chosen, options=options)
        tables = ("mdm", "oneshot") if config.evaluate.oneshot else ("mdm",)
        typer.echo(
            f"MDM: evaluated {len({r['seed'] for r in rows})} seeds; wrote "
            f"{', '.join(str(layout.eval_table(t)) for t in tables)}"
        )
    if protocol in ("mdi", "all") and config.mdi is not None:
        rows = stage_mdi(layout, config, seeds=chosen, options=options)
        typer.echo(f"MDI: evaluated {len({r['seed'] for r in rows})} seeds; wrote {layout.eval_table('mdi')}")


@app.command()
@user_errors
def benchmark(
    out: Path = OUT,
    seeds: Optional[str] = typer.Option(None, "--seeds", help="Unseen seeds (default: the run's benchmark.seeds)."),
    methods: Optional[str] = typer.Option(
        None,
        "--methods",
        help=f"Comma-separated, of: {listed(benchmark_methods)} (default: benchmark.methods; "
        "`metadagger config methods` says what each is).",
    ),
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
    report: bool = typer.Option(
        True, "--report/--no-report", help="Write the run's report/report.md again at the end (default: yes)."
    ),
) -> None:
    """Success against expert queries: DAgger, gated DAgger and MetaL DAgger on unseen seeds.

    Writes benchmark/queries.csv, summary.json and queries.png, then the run's report. Only the missing rows are run."""
    from metadagger.evaluation.report.build import build_report
    from metadagger.pipeline.stages import load_run, stage_benchmark
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.yaml_config import parse_seeds

    options = stage_options(rebuild, executor, workers, address)
    layout = RunLayout(out)
    config = load_run(out, overrides)
    if config.benchmark is None:
        raise UserError(
            f"run {out} has no benchmark section; add one with --set 'benchmark={{seeds: 5000-5009}}' or use a preset "
            "that has one"
        )
    chosen = tuple(m.strip() for m in methods.split(",") if m.strip()) if methods is not None else None
    rows = stage_benchmark(
        layout, config, seeds=parse_seeds(seeds) if seeds is not None else None, methods=chosen, options=options
    )
    typer.echo(
        f"benchmark: {len(rows)} rows on {len({r['seed'] for r in rows})} seeds; wrote {layout.benchmark_table}, "
        f"{layout.benchmark_summary}, {layout.benchmark_figure}"
    )
    if report:
        typer.echo(f"wrote {build_report(layout)}")
    else:
        typer.echo(f"the report is left as it was: `metadagger report --out {out}` writes it again")


@app.command()
@user_errors
def diagnose(
    out: Path = OUT,
    overrides: list[str] = SET,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Does a mapper learn anything? Errors of every kind and control on the validation pairs.

    Function- and weight-space errors, the noise ceiling, memorisation and the data-scaling curve
    (diagnostics/mapping.json, scaling.png; a section of the report)."""
    from metadagger.pipeline.stages import load_run, stage_diagnose
    from metadagger.runfolder.layout import RunLayout

    options = stage_options(False, executor, workers, address)
    layout = RunLayout(out)
    summary = stage_diagnose(layout, load_run(out, overrides), options=options)
    typer.echo(
        f"diagnostics: {len(summary['methods']) - 1} kinds and controls on {summary['val_pairs']} validation pairs; "
        f"wrote {layout.diagnostics_summary}, {layout.diagnostics_figure}"
    )


@app.command()
@user_errors
def export(
    out: Path = OUT,
    content: str = typer.Option(
        ...,
        "--content",
        help="demos (the expert's), dagger (the pairs' per-seed DAgger rollouts) or "
        "pairs-data (both: everything each pair was fit on).",
    ),
    fmt: str = typer.Option("minari", "--format", help="minari (the only format)."),
    name: str = typer.Option(..., "--name", help="Minari dataset id, e.g. metadagger/carracing-demos-v0."),
    seeds: Optional[str] = typer.Option(None, "--seeds", help="Seeds to export (default: the run's pairs.seeds)."),
    author: str = typer.Option("metadagger", "--author", help="The dataset's author (Minari's author)."),
    author_email: Optional[str] = typer.Option(None, "--author-email", help="The author's email (optional)."),
    overrides: list[str] = SET,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Write a run's episodes as a Minari dataset (docs/minari.md).

    Each step holds the observation, the learner's action, the expert's label, whether it was queried, the DAgger round
    and the seed."""
    from metadagger.metal_dagger.export import check_export
    from metadagger.pipeline.outputs import stage_export
    from metadagger.pipeline.stages import load_run
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.yaml_config import parse_seeds

    seed_list = parse_seeds(seeds) if seeds is not None else None  # a malformed value before the dataset store is read
    check_export(content, fmt, name)
    options = stage_options(False, executor, workers, address)
    summary = stage_export(
        RunLayout(out),
        load_run(out, overrides),
        content=content,
        name=name,
        seeds=seed_list,
        author=author,
        author_email=author_email,
        options=options,
    )
    checked = (
        ""
        if content == "demos"
        else f", {summary['checked']} re-run pairs equal to the stored ones"
        if summary["checked"]
        else ", no stored pair of these seeds to compare the re-run with"
    )
    typer.echo(
        f"export: {summary['episodes']} episodes, {summary['steps']} steps{checked}; wrote Minari dataset {name} "
        f"({summary['dataset']}); read it with minari.load_dataset({name!r})"
    )


@app.command()
@user_errors
def video(
    out: Path = OUT,
    seed: int = typer.Option(..., "--seed", help="The seed to show, e.g. one of benchmark.seeds."),
    methods: str = typer.Option(
        "bc,dm,dagger",
        "--methods",
        help="Comma-separated: expert, bc, dagger and mapper kinds of the run (dm, ridge, pistar-head, ...).",
    ),
    fps: int = typer.Option(30, "--fps", help="Frames (env steps) per second."),
    scale: int = typer.Option(3, "--scale", help="Pixels per observation pixel."),
    gif_stride: int = typer.Option(3, "--gif-stride", help="The GIF keeps every n-th frame (the MP4 keeps all)."),
    overrides: list[str] = SET,
) -> None:
    """One seed's rollouts side by side, as the learner saw them (needs the video extra).

    Each frame shows the method, step, reward and expert queries: RUN/videos/<seed>-<methods>.mp4 and .gif."""
    from metadagger.pipeline.outputs import stage_video
    from metadagger.pipeline.stages import load_run
    from metadagger.runfolder.layout import RunLayout

    names = [m.strip() for m in methods.split(",") if m.strip()]
    mp4, gif = stage_video(
        RunLayout(out), load_run(out, overrides), seed=seed, methods=names, fps=fps, scale=scale, gif_stride=gif_stride
    )
    typer.echo(f"wrote {mp4} and {gif}")


@app.command()
@user_errors
def report(out: Path = OUT) -> None:
    """Build report/report.md and its figures from the run's CSV/JSON artifacts alone."""
    from metadagger.evaluation.report.build import build_report
    from metadagger.runfolder.layout import RunLayout

    typer.echo(f"wrote {build_report(RunLayout(out))}")


@app.command()
@user_errors
def status(out: Path = OUT) -> None:
    """Where a run stands: who writes it now, each stage and the seeds it has done.

    Read from the run's files alone (nothing is run or loaded): the process holding its write lock,
    each stage's state and wall time (stage_times.json), and the seeds each per-seed stage has logged."""
    from metadagger.pipeline.run_status import run_status
    from metadagger.pipeline.stages import load_run
    from metadagger.runfolder.layout import RunLayout

    typer.echo("\n".join(run_status(RunLayout(out), load_run(out))))


@app.command()
@user_errors
def reproduce(
    task: str = TASK,
    preset: str = PRESET,
    out: Path = typer.Option(Path("runs/quick"), "--out", help="Run folder; an unfinished run resumes."),
    presets: Optional[Path] = PRESETS_FILE,
    overrides: list[str] = SET,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
    device: Optional[str] = DEVICE,
    log: Optional[str] = typer.Option(
        None,
        "--log",
        help="tensorboard: also write every stage's curves and evaluations as "
        "TensorBoard scalars under OUT/tb (needs the tensorboard extra); none: off. Sets the "
        "run's log key (default: the run's, none for a new run).",
    ),
    diagnose: bool = typer.Option(
        False,
        "--diagnose",
        help="also run the mapping diagnostics on the validation pairs "
        "after the benchmark (`metadagger diagnose`; a section of the report).",
    ),
) -> None:
    """Every stage: pistar -> pairs -> mappers -> evaluate -> mdi -> benchmark -> diagnose -> report.

    mdi runs where the config has an mdi section, benchmark where it has a benchmark section, diagnose with --diagnose.
    Finished work is resumed; what a changed config or input made stale is rebuilt."""
    from metadagger.pipeline.run_config import check_log
    from metadagger.pipeline.stages import load_run
    from metadagger.pipeline.stages import reproduce as run_all
    from metadagger.runfolder.layout import RunLayout

    if log is not None:
        check_log(log, "--log")
    overrides = [*overrides, f"log={log}"] if log is not None else overrides
    path = run_all(
        task,
        preset,
        out,
        presets_file=presets,
        overrides=overrides,
        diagnose=diagnose,
        device=device,
        options=stage_options(False, executor, workers, address),
    )
    typer.echo(path.read_text())
    typer.echo(f"wrote {path}")
    if load_run(out).log == "tensorboard":
        tb = RunLayout(out).tb_dir
        typer.echo(f"wrote TensorBoard scalars to {tb}; view them with `tensorboard --logdir {tb}`")
