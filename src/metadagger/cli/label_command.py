"""``metadagger label``: a gate's DAgger rounds on one seed of a run, a person labelling them at a local page."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import urlsplit

import typer

from metadagger.cli.options import OUT, listed, user_errors

#: Merged into the top-level command line (no group name of its own).
label_app = typer.Typer()


def _gates() -> list[str]:
    from metadagger.imitation.gate_registry import gated_names

    return gated_names()  # the oracle, a reference that reads the scripted expert's labels, is no gate a session takes


@label_app.command()
@user_errors
def label(
    out: Path = OUT,
    seed: int = typer.Option(..., "--seed", help="The seed to label: an unseen one, e.g. one of benchmark.seeds."),
    gate: str = typer.Option(..., "--gate", help=f"The gate that chooses the states: {listed(_gates)}."),
    setting: float = typer.Option(
        ...,
        "--setting",
        help="The gate's setting: one value of the run's grid (benchmark.grids), so that the benchmark has the row "
        "to compare with.",
    ),
    expert: str = typer.Option(
        "person",
        "--expert",
        help="person: label at the page this command serves; scripted: the task's scripted expert answers "
        "(the same session without a person, to compare with).",
    ),
    port: int = typer.Option(0, "--port", help="The page's port on 127.0.0.1 (0: a free one)."),
) -> None:
    """Gated DAgger on one seed of a run with a person as the expert, at a page on 127.0.0.1.

    The page shows each state the gate chose and takes the label; the loop refits and rolls out the next round by
    itself. Every label is kept as it is given: run the same command again to resume (docs/label.md)."""
    from metadagger.evaluation.benchmark.ledger import effort
    from metadagger.label.session import benchmark_gap, finished_rows, plan_of_run, run_label
    from metadagger.pipeline.stages import load_run
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.device import use_device
    from metadagger.utils.jsonl import read_lines

    layout = RunLayout(out)
    config = load_run(out, [])
    use_device(config.device)
    plan = plan_of_run(layout, config, seed=seed, gate=gate, setting=setting)
    gap = benchmark_gap(config, plan)
    if gap:
        typer.echo(f"warning: {gap}", err=True)
    finished = finished_rows(layout, plan, expert) is not None

    def announce(url: str) -> None:
        port = urlsplit(url).port
        typer.echo(f"label the states at {url}")
        typer.echo(
            f"(served to this machine only; from another, forward the port: ssh -L {port}:127.0.0.1:{port} HOST)"
        )

    rows = run_label(layout, plan, expert=expert, port=port, announce=announce)
    session = plan.session(layout, expert)
    spent = effort(read_lines(session.labels, called="label record"), len(rows))
    last = rows[-1]
    if finished:
        typer.echo(
            f"session {session.root} is finished: nothing is left to label (move its folder away to begin again)"
        )
    typer.echo(
        f"round {len(rows)}: {'success' if last['success'] else 'failure'} at {last['expert_queries']} queries, "
        f"{spent['labels']} labelled by {spent['labelled_by']} in {spent['seconds']:g} s"
    )
    written = "holds" if finished else "wrote"
    typer.echo(f"{written} {session.root} (labels.jsonl, rows.jsonl, heads/); `metadagger report --out {out}` shows it")
