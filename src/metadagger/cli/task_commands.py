"""``metadagger demo``, ``expert`` and ``check-task``: a task's expert and a small DAgger run, no run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from metadagger.cli.options import BUILTIN_PRESET, PRESETS_FILE, TASK, user_errors
from metadagger.errors import UserError

#: Merged into the top-level command line (no group name of its own).
task_app = typer.Typer()


@task_app.command()
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


@task_app.command()
@user_errors
def expert(
    task: str = TASK,
    seeds: str = typer.Option("0-9", "--seeds", help="Seeds: a range '0-99', a list '1,5,9' or one seed."),
    out: Optional[Path] = typer.Option(
        None, "--out", help="Also write a record here (JSON): the task as built, the seeds and the per-seed rows."
    ),
    preset: Optional[str] = typer.Option(
        None,
        "--preset",
        help="Build the task as this preset of pipeline/presets/<task>.yaml (or of --presets) does: its "
        "task_options and max_episode_steps, a variant's expert; default: the task's own defaults.",
    ),
    presets: Optional[Path] = PRESETS_FILE,
) -> None:
    """Measure the task's expert (acting through the learner's action space) on seeds."""
    from metadagger.evaluation.expert import evaluate_expert, expert_record, expert_table
    from metadagger.pipeline.run_config import resolve_config
    from metadagger.tasks import make_task
    from metadagger.utils.io import check_output_file, write_json
    from metadagger.utils.yaml_config import parse_seeds

    if out is not None:
        check_output_file(out, "--out")
    seed_list = parse_seeds(seeds)
    if presets is not None and preset is None:
        raise UserError(f"--presets {presets} names presets, but no --preset says which; add --preset NAME")
    kwargs = {} if preset is None else resolve_config(task, preset, presets).task_kwargs
    rows = evaluate_expert(make_task(task, **kwargs), seed_list)
    typer.echo(expert_table(rows))
    if out is not None:
        write_json(out, expert_record(task, preset, kwargs, seeds, rows, None if presets is None else str(presets)))
        typer.echo(f"wrote {out}")


@task_app.command("check-task")
@user_errors
def check_task_cmd(
    task: str = TASK,
    seeds: str = typer.Option(
        "0-9", "--seeds", help="Seeds the expert is measured on: a range '0-9', a list '1,5,9' or one seed."
    ),
) -> None:
    """Check a task's code, then measure its expert on seeds.

    The checks: observation and action spaces, the expert's labels, combine and to_label, seeded episodes; the measure:
    success, episode lengths and steps per second. Each problem is one line naming the Task method; exit 2."""
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
