"""``metadagger config ...``: what a run would use, and every method, gate and mapper kind there is."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from metadagger.cli.options import PRESET, PRESETS_FILE, SET, TASK, user_errors
from metadagger.evaluation.benchmark.methods import benchmark_methods
from metadagger.mapping.registry import kind_names

config_app = typer.Typer(no_args_is_help=True, help="Inspect run configs.")


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
