"""What every command of the command line shares: its options, and how a user error ends it."""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Callable, TypeVar

import typer

from metadagger.errors import UserError

if TYPE_CHECKING:
    from metadagger.runfolder.driver import StageOptions

F = TypeVar("F", bound=Callable[..., object])


def listed(names: Callable[[], object]) -> str:
    """``names()`` joined by commas for a help text; where a plug-in fails to load, a pointer to the
    command that says why (the help must not fail: the command then prints the one-line error)."""
    try:
        return ", ".join(names())  # type: ignore[call-overload]
    except UserError:
        return "(an installed plug-in fails to load: run the command to see which)"


def user_errors(fn: F) -> F:
    """Turn a UserError raised by ``fn`` into one clear line and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except UserError as exc:
            print_error(str(exc))
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


def print_error(message: str) -> None:
    """``message`` as the one ``error: ...`` line on stderr."""
    typer.secho(f"error: {message}", err=True, fg=typer.colors.RED)


TASK = typer.Option("carracing", "--task", help="Task name: carracing, fetch, or one an installed package adds.")
PRESET = typer.Option(
    "quick", "--preset", help="Preset from pipeline/presets/<task>.yaml (quick, paper or ci) or from --presets."
)
PRESETS_FILE = typer.Option(
    None, "--presets", help="YAML file of your own presets (same layout as pipeline/presets/<task>.yaml)."
)
BUILTIN_PRESET = typer.Option(
    "quick", "--preset", help="Preset from pipeline/presets/<task>.yaml (quick, paper or ci)."
)
DEVICE = typer.Option(
    None,
    "--device",
    help="Where a new run computes: cpu, cuda (a GPU) or auto (cuda where torch sees one). A run keeps "
    "the device it started on (default: cpu for a new run, the folder's for a started one).",
)
OUT = typer.Option(..., "--out", help="Run folder (holds config.yaml and every stage's artifacts).")
SET = typer.Option(
    [],
    "--set",
    help="Override a config field: section.key=value, the value read as YAML "
    "(e.g. --set pairs.dagger_rounds=4 --set 'evaluate.methods=[dm, sam]'); repeatable.",
)
REBUILD = typer.Option(
    False,
    "--rebuild",
    help="Redo this stage's work that was made from other inputs (another pi*, "
    "other pairs or settings) instead of refusing.",
)
EXECUTOR = typer.Option(
    "local", "--executor", help="local (process pool), ray, or inline (one job at a time in this process)."
)
WORKERS = typer.Option(None, "--workers", help="Parallel workers (default: all cores / the Ray cluster's CPUs).")
ADDRESS = typer.Option(
    None, "--address", help="Ray cluster: ray://HEAD:10001, HEAD:6379 or auto (default: start a local Ray instance)."
)


def stage_options(rebuild: bool, executor: str, workers: int | None, address: str | None) -> StageOptions:
    """A stage's options from the command line, its executor options checked before any work."""
    from metadagger.runfolder.driver import StageOptions
    from metadagger.utils.executors import check_executor_options

    check_executor_options(executor, workers, address)
    return StageOptions(rebuild=rebuild, executor=executor, workers=workers, address=address)
