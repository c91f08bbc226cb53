"""``metadagger label`` on the command line: a scripted session to its report, run again once finished, a
warning where the benchmark has no row to compare with, and one line for each session that cannot run."""

from __future__ import annotations

import pytest
from corridor_session import SEED, session_args
from typer.testing import CliRunner

from metadagger.cli.main import app

runner = CliRunner()


def test_a_scripted_session_is_written_and_reported(run):
    result = runner.invoke(app, session_args(run.root, "--expert", "scripted"))
    assert result.exit_code == 0, result.output
    session = run.label_session("scripted", "dagger-safe", "0.5", SEED)
    assert "round 3: success at 40 queries, 10 labelled by scripted in 0 s" in result.output
    assert f"wrote {session.root} (labels.jsonl, rows.jsonl, heads/)" in result.output
    reported = runner.invoke(app, ["report", "--out", str(run.root)])
    assert reported.exit_code == 0, reported.output
    report = run.report.read_text()
    assert "## A person as the expert" in report
    assert "### DAgger, SafeDAgger gate 0.5, seed 300, labelled by scripted" in report
    assert "| round | learner | queries | takeovers | labels | seconds | switches | labelled by |" in report
    assert "| 3 | success (30 steps) | 40 | 6 | 10 | 0.0 | 5 | scripted |" in report


def test_a_finished_session_run_again_says_so_and_changes_nothing(run):
    assert runner.invoke(app, session_args(run.root, "--expert", "scripted")).exit_code == 0
    session = run.label_session("scripted", "dagger-safe", "0.5", SEED)
    written = {p: p.stat().st_mtime_ns for p in session.root.rglob("*") if p.is_file() and p.name != ".lock"}
    result = runner.invoke(app, session_args(run.root, "--expert", "scripted"))
    assert result.exit_code == 0, result.output
    assert f"session {session.root} is finished: nothing is left to label" in result.output
    assert "round 3: success at 40 queries, 10 labelled by scripted in 0 s" in result.output
    assert f"holds {session.root} (labels.jsonl, rows.jsonl, heads/); `metadagger report --out" in result.output
    assert {p: p.stat().st_mtime_ns for p in session.root.rglob("*") if p.is_file() and p.name != ".lock"} == written


def test_a_setting_off_the_runs_grid_is_warned_of(run):
    result = runner.invoke(app, session_args(run.root, "--expert", "scripted", "--setting", "0.8"))
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert warnings == [
        "warning: --setting 0.8 is not in the run's grid of dagger-safe (0.5), so the benchmark has no row to compare "
        "with; choose one of those"
    ]


def test_the_help_lists_the_gates():
    result = runner.invoke(app, ["label", "--help"], env={"COLUMNS": "300"})
    assert (
        result.exit_code == 0
        and "random, ensemble, safe, novelty, least-confidence, margin, entropy, thrifty, conformal." in result.output
        and "oracle" not in result.output
    )


@pytest.mark.parametrize(
    "args, says",
    [
        (["--gate", "oracle"], "gate 'oracle' is a reference that reads the scripted expert's labels"),
        (["--gate", "nope"], "unknown gate 'nope': expected one of random, ensemble, safe, novelty, least-conf"),
        (["--seed", "200"], "--seed 200 was used for pi* or the pairs; label an unseen seed"),
        (["--setting", "2"], "SafeGate"),
        (["--expert", "robot"], "--expert must be one of person, scripted, got 'robot'"),
    ],
)
def test_a_session_that_cannot_run_is_one_line(run, args, says):
    base = dict(zip(session_args(run.root)[1::2], session_args(run.root)[2::2]))
    base.update(dict(zip(args[::2], args[1::2])))
    result = runner.invoke(app, ["label", *[x for pair in base.items() for x in pair]])
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 2 and len(errors) == 1 and says in errors[0], result.output
    assert not any(run.label_dir.glob("*/*/*/labels.jsonl"))


def test_a_port_in_use_is_one_line_and_begins_nothing(run, closed_port):
    result = runner.invoke(app, session_args(run.root, "--port", str(closed_port)))
    assert result.exit_code == 2, result.output
    assert f"error: --port {closed_port} cannot be used on 127.0.0.1" in result.output
    assert not run.label_session("person", "dagger-safe", "0.5", SEED).stamp.exists()
