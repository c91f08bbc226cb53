"""``metadagger results ...``: the results registry (:mod:`metadagger.results`)."""

from __future__ import annotations

from pathlib import Path

import typer

from metadagger.cli.options import OUT, user_errors

results_app = typer.Typer(no_args_is_help=True, help="The results registry (results/) and the docs' generated blocks.")

REGISTRY_OPTION = typer.Option(Path("results"), "--results", help="The registry folder.")
ROOT_OPTION = typer.Option(Path("."), "--root", help="The repository root (README.md, docs/).")


@results_app.command("add")
@user_errors
def results_add_cmd(
    out: Path = OUT,
    name: str = typer.Option(..., "--name", help="The canonical run it is (see docs/results.md)."),
    beside: str = typer.Option(..., "--beside", help="What else ran on the machine while the run was made."),
    registry: Path = REGISTRY_OPTION,
) -> None:
    """Reproduce run folder --out with this code, then keep it in the registry as run --name.

    It resumes: a current run has nothing left to do. The registry keeps its small artifacts and a manifest."""
    from metadagger.results.registry import add_run

    target = add_run(out, name, beside=beside, registry=registry)
    typer.echo(f"wrote {target}")


@results_app.command("calibration")
@user_errors
def results_calibration_cmd(
    out: Path = OUT,
    name: str = typer.Option(..., "--name", help="The variant's name in its task's calibration table."),
    registry: Path = REGISTRY_OPTION,
) -> None:
    """Keep calibration run --out as a row of its task's calibration table.

    The run is made by scripts/calibrate.sh on pair seeds; the table is the `calibration TASK` block of
    the task's docs page."""
    from metadagger.results.calibration import add_calibration

    typer.echo(f"wrote {add_calibration(out, name, registry)}")


@results_app.command("build")
@user_errors
def results_build_cmd(root: Path = ROOT_OPTION, registry: Path = REGISTRY_OPTION) -> None:
    """Write every generated block of README.md and docs/ from the registry."""
    from metadagger.results.blocks import build

    changed = build(root, registry=root / registry)
    for block in changed:
        typer.echo(f"rewrote {block}")
    typer.echo(f"{len(changed)} block(s) rewritten")


@results_app.command("check")
@user_errors
def results_check_cmd(
    root: Path = ROOT_OPTION,
    registry: Path = REGISTRY_OPTION,
    strict: bool = typer.Option(False, "--strict", help="Also exit 1 when any registry run is stale."),
) -> None:
    """Exit 1, naming each block, when README.md or docs/ differ from what `results build` writes.

    Stale runs pass: their blocks mark them. With --strict, also exit 1 naming each stale run."""
    from metadagger.results.blocks import build
    from metadagger.results.registry import load_registry
    from metadagger.results.staleness import registry_staleness, stale_summary

    changed = build(root, registry=root / registry, check=True)
    for block in changed:
        typer.echo(f"differs from what build writes: {block}", err=True)
    if changed:
        typer.echo("run `metadagger results build` and commit the result", err=True)
    stale = {n: r for n, r in registry_staleness(load_registry(root / registry)).items() if r} if strict else {}
    for name, reasons in stale.items():
        typer.echo(f"stale run: {name} ({stale_summary(reasons)}); see `metadagger results status`", err=True)
    if changed or stale:
        raise typer.Exit(1)
    typer.echo("every generated block is what build writes" + ("; every registry run is current" if strict else ""))


@results_app.command("status")
@user_errors
def results_status_cmd(root: Path = ROOT_OPTION, registry: Path = REGISTRY_OPTION) -> None:
    """Every canonical run: current, stale or missing, with the command that makes it again.

    A stale run's line says why, as `setting: run's -> today's`; each run's line gives the wall time it last took."""
    from metadagger.results.registry import load_registry
    from metadagger.results.staleness import registry_status

    rows = registry_status(load_registry(root / registry))
    for row in rows:
        typer.echo(f"{row['name']}: {row['state']}, last took {row['wall'] or 'never made'}")
        for reason in row["reasons"]:
            typer.echo(f"    {reason}")
        if row["state"] != "current":
            typer.echo(f"    make it: {row['command']}")
    counts = {state: sum(r["state"] == state for r in rows) for state in ("current", "stale", "missing")}
    typer.echo(", ".join(f"{n} {state}" for state, n in counts.items()))


@results_app.command("compare")
@user_errors
def results_compare_cmd(
    old: Path = typer.Argument(..., help="The old run folder or registry run (e.g. one checked out from git)."),
    new: Path = typer.Argument(..., help="The new run folder or registry run of the same preset."),
    json_out: Path = typer.Option(None, "--json", help="Also write the comparison as JSON here."),
) -> None:
    """Every success rate of NEW's tables beside the 95% Wilson interval of OLD's.

    What a change of numerics moved: the rates outside the intervals are counted at the end."""
    from metadagger.results.compare import compare_runs, comparison_lines
    from metadagger.utils.io import write_json

    comparison = compare_runs(old, new)
    if json_out is not None:
        write_json(json_out, comparison)
    typer.echo("\n".join(comparison_lines(comparison)))
