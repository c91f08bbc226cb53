"""The ``metadagger`` command line: thin wrappers that build a config and call the library.

A :class:`~metadagger.errors.UserError` becomes one ``error: ...`` line on stderr and exit code 2
(:func:`~metadagger.cli.options.user_errors`, beside the options every command shares); the
process around the commands (usage errors, signals, exit codes) is :mod:`metadagger.cli.entry`;
the ``bench`` commands are :mod:`metadagger.cli.bench_commands`, the ``results`` ones
:mod:`metadagger.cli.results_commands`.

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
from metadagger.cli.options import (
    ADDRESS,
    BUILTIN_PRESET,
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
from metadagger.evaluation.methods import benchmark_methods
from metadagger.mapping.registry import kind_names, trained_names

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Meta-Learning DAgger: imitation learning that maps BC weights to DAgger weights.",
)
app.add_typer(bench_app, name="bench")
app.add_typer(results_app, name="results")
config_app = typer.Typer(no_args_is_help=True, help="Inspect run configs.")
app.add_typer(config_app, name="config")


@app.callback()
def _setup() -> None:
    """Meta-Learning DAgger: imitation learning that maps BC weights to DAgger weights."""
    import torch

    # one thread everywhere (driver and workers): the same config and seeds give the same
    # weights on any machine, whatever its core count
    torch.set_num_threads(1)


@app.command()
@user_errors
def demo(
    task: str = TASK,
    preset: str = BUILTIN_PRESET,
    out: Path = typer.Option(Path("runs/demo"), "--out", help="Run folder to write to."),
    rounds: Optional[int] = typer.Option(None, "--rounds", help="Override the preset's DAgger rounds."),
    epochs: Optional[int] = typer.Option(None, "--epochs", help="Override the preset's BC epochs per fit."),
    demos: Optional[str] = typer.Option(
        None,
        "--demos",
        help="Clone from this Minari dataset (its spaces must match the "
        "task's learner) instead of the expert's demonstrations of the train seeds.",
    ),
) -> None:
    """BC from expert demos, then DAgger rounds; both evaluated on unseen seeds."""
    from metadagger.cli.demo import demo_config, run_demo

    config = demo_config(task, preset, rounds=rounds, epochs=epochs, demos=demos)
    result = run_demo(config, out)
    typer.echo(result.table)
    typer.echo(f"wrote {result.folder}")


@app.command()
@user_errors
def expert(
    task: str = TASK,
    seeds: str = typer.Option("0-9", "--seeds", help="Seeds: a range '0-99', a list '1,5,9' or one seed."),
    out: Optional[Path] = typer.Option(None, "--out", help="Also write the per-seed rows as JSON here."),
) -> None:
    """Measure the task's expert (acting through the learner's action space) on seeds."""
    from metadagger.evaluation.expert import evaluate_expert, expert_table
    from metadagger.tasks import make_task
    from metadagger.utils.io import check_output_file, write_json
    from metadagger.utils.yaml_config import parse_seeds

    if out is not None:
        check_output_file(out, "--out")
    rows = evaluate_expert(make_task(task), parse_seeds(seeds))
    typer.echo(expert_table(rows))
    if out is not None:
        write_json(out, rows)
        typer.echo(f"wrote {out}")


@app.command("check-task")
@user_errors
def check_task_cmd(
    task: str = TASK,
    seeds: str = typer.Option(
        "0-9", "--seeds", help="Seeds the expert is measured on: a range '0-9', a list '1,5,9' or one seed."
    ),
) -> None:
    """Check a task's code (observation and action spaces, the expert's labels, combine and
    to_label, seeded episodes), then measure its expert on seeds: success, episode lengths and
    steps per second. Each problem is one line naming the Task method; exit 2."""
    import time

    from metadagger.evaluation.expert import evaluate_expert, expert_table
    from metadagger.tasks import make_task
    from metadagger.tasks.checks import check_task_code
    from metadagger.utils.yaml_config import parse_seeds

    seed_list = parse_seeds(seeds)
    built = make_task(task)
    check_task_code(built)
    env = built.make_base_env()
    try:
        typer.echo(
            f"{task}: the task's code passes the checks (observations {env.observation_space.dtype} "
            f"{tuple(env.observation_space.shape)}, learner actions {built.learner_action_space}, "
            f"{built.max_episode_steps} steps an episode at most)"
        )
    finally:
        env.close()
    start = time.perf_counter()
    rows = evaluate_expert(built, seed_list)
    typer.echo(expert_table(rows, seconds=time.perf_counter() - start))
    if not any(r["success"] for r in rows):
        typer.echo(
            f"warning: the expert succeeds on none of {len(rows)} seeds: is_success or the expert is wrong, "
            "and nothing can be imitated",
            err=True,
        )


@app.command()
@user_errors
def groundtruth(
    task: str = TASK,
    preset: str = PRESET,
    out: Path = OUT,
    presets: Optional[Path] = PRESETS_FILE,
    overrides: list[str] = SET,
    rebuild: bool = REBUILD,
    device: Optional[str] = DEVICE,
) -> None:
    """Train pi*: BC on expert demos of K seeds, then DAgger rounds over all of them."""
    from metadagger.metal.groundtruth import pistar_rates
    from metadagger.pipeline.stages import init_run, stage_groundtruth
    from metadagger.runfolder.driver import StageOptions
    from metadagger.runfolder.layout import RunLayout

    layout = RunLayout(out)
    config = init_run(out, task, preset, presets, overrides, device)
    metrics = stage_groundtruth(layout, config, StageOptions(rebuild=rebuild))
    typer.echo(f"pi*: {pistar_rates(metrics)}")
    if metrics["unseen_seeds"]["success_rate"] < config.groundtruth.min_success:
        typer.echo(
            f"warning: pi* is below groundtruth.min_success={config.groundtruth.min_success:g} on its unseen seeds: "
            'the pairs stage will refuse it (docs/custom_task.md, "Making pi* work on a new task")',
            err=True,
        )
    if metrics.get("bc_selection"):
        choice = metrics["bc_selection"]
        typer.echo(
            f"pi* is epoch {choice['epoch']} of its BC fit: {choice['successes']}/{choice['episodes']} held-out seeds"
        )
    typer.echo(f"wrote {layout.groundtruth}")


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
    from metadagger.metal.pairs import negligible_change_warning

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
    """Train mappers on the run's kept pairs (curves.csv and curves.png beside each), one kind
    per worker."""
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
    """Search a mapper's hyperparameters with Optuna: trials train on the run's training pairs and
    are scored on its validation pairs (never on evaluation seeds); the study in tune/<kind>.db
    resumes, the best trial goes to tune/<kind>.yaml (docs/tuning.md)."""
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
    """MDM and one-shot evaluation of BC, every mapper and the controls on unseen seeds, and the
    MDI protocol (DAgger-MDI vs DAgger-BC vs DAgger) for runs whose config has an mdi section.
    Only the missing (seed, method) rows are evaluated."""
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
) -> None:
    """Success against expert queries: DAgger, gated DAgger baselines and MetaL DAgger on unseen
    seeds (benchmark/queries.csv, summary.json, queries.png). Only the missing rows are run."""
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


@app.command()
@user_errors
def diagnose(
    out: Path = OUT,
    overrides: list[str] = SET,
    executor: str = EXECUTOR,
    workers: Optional[int] = WORKERS,
    address: Optional[str] = ADDRESS,
) -> None:
    """Does a mapper learn anything? Function- and weight-space errors of every kind and control
    on the validation pairs, the noise ceiling, memorisation and the data-scaling curve
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
    what: str = typer.Option(
        ...,
        "--what",
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
    """Write a run's episodes as a Minari dataset: observations, the learner's action, the expert's
    label, whether it was queried, the DAgger round and the seed (docs/minari.md)."""
    from metadagger.metal.export import check_export
    from metadagger.pipeline.stages import load_run, stage_export
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.yaml_config import parse_seeds

    seed_list = parse_seeds(seeds) if seeds is not None else None  # a malformed value before the dataset store is read
    check_export(what, fmt, name)
    options = stage_options(False, executor, workers, address)
    summary = stage_export(
        RunLayout(out),
        load_run(out, overrides),
        what=what,
        name=name,
        seeds=seed_list,
        author=author,
        author_email=author_email,
        options=options,
    )
    checked = (
        ""
        if what == "demos"
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
    """One seed's rollouts side by side, as the learner saw them, with method, step, reward and
    expert queries: RUN/videos/<seed>-<methods>.mp4 and .gif (needs the video extra)."""
    from metadagger.pipeline.stages import load_run, stage_video
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
    from metadagger.evaluation.report import build_report
    from metadagger.runfolder.layout import RunLayout

    typer.echo(f"wrote {build_report(RunLayout(out))}")


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
    """groundtruth -> pairs -> mappers -> evaluate -> mdi (runs with an mdi section) -> benchmark
    (runs with a benchmark section) -> diagnose (with --diagnose) -> report,
    resuming finished work and rebuilding what a changed config or input made stale."""
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


@config_app.command("methods")
@user_errors
def config_methods() -> None:
    """List every benchmark method, gate and mapper kind metadagger knows, installed plug-ins' included."""
    from metadagger.imitation.gate_registry import gate_declarations
    from metadagger.mapping.registry import get_kind

    typer.echo("benchmark methods (benchmark.methods, --methods):")
    for method in benchmark_methods().values():
        typer.echo(f"  {method.name}: {method.summary}{' [reference, never ranked]' if method.reference else ''}")
    typer.echo("gates (method dagger-<gate>; default grid; options shared with the benchmark):")
    for gate in gate_declarations().values():
        shared = ", ".join(f"{field}={option}" for field, option in gate.shared.items())
        typer.echo(
            f"  {gate.name}: {gate.label}; {gate.gate.setting} in {list(gate.grid)}"
            + (f"; {shared}" if shared else "")
            + f"; {gate.summary}"
        )
    typer.echo("mapper kinds (evaluate.methods, mdm-<kind>):")
    for name in kind_names():
        kind = get_kind(name)
        typer.echo(f"  {name}: {kind.label}; {kind.summary}")


@config_app.command("show")
@user_errors
def config_show(
    task: str = TASK, preset: str = PRESET, presets: Optional[Path] = PRESETS_FILE, overrides: list[str] = SET
) -> None:
    """Print the resolved config of a preset with --set overrides, as YAML (what a new run would use)."""
    from metadagger.pipeline.run_config import resolve_config
    from metadagger.utils.yaml_config import dump_yaml

    typer.echo(dump_yaml(resolve_config(task, preset, presets, overrides)), nl=False)
