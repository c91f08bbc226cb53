"""``metadagger status --out RUN``: where a run stands, from its files alone."""

from __future__ import annotations

import datetime
import json
import os
import re
import socket
import subprocess

from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.pipeline.run_config import init_run, load_run
from metadagger.pipeline.run_status import run_status
from metadagger.runfolder.driver import RowLog
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import LOCK_FILE

runner = CliRunner()


def _row(lines, stage):
    return next(line for line in lines if line.startswith(f"| {stage} |"))


def _lock(run, pid):
    holder = {
        "pid": pid,
        "host": socket.gethostname(),
        "command": "metadagger reproduce",
        "since": "2026-01-01 10:00:00",
    }
    (run / LOCK_FILE).write_text(json.dumps(holder))


def _times(run, **entries):
    (run / "stage_times.json").write_text(json.dumps(entries))


def test_a_run_being_written_names_its_writer_its_running_stage_and_the_seeds_logged(tmp_path):
    run = tmp_path / "run"
    config = init_run(run, "carracing", "ci")
    finished = {"seconds": 70.0, "total_seconds": 95.0, "finished": "2026-01-01T10:05:00+00:00"}
    just_now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    running = {"seconds": 30.0, "total_seconds": 30.0, "finished": just_now, "stopped": True, "earlier_seconds": 0.0}
    _times(run, pistar=finished, pairs=running)
    _lock(run, os.getpid())
    RowLog(RunLayout(run).benchmark_log).append({"seed": config.benchmark.seeds[0], "entries": {"bc": []}}, {"bc": {}})

    lines = run_status(RunLayout(run), load_run(run))
    writer = f"pid {os.getpid()} on {socket.gethostname()}"
    assert lines[1] == f"written now by {writer} (`metadagger reproduce`, since 2026-01-01 10:00:00)"
    assert _row(lines, "pistar").startswith("| pistar | finished | 1 min 35 s |")
    # 30 s at its last heartbeat, written just now: about 30 s into the call
    assert re.match(r"\| pairs \| running \(3\d\.\d s into this call\) \| 30\.0 s \|", _row(lines, "pairs"))
    assert _row(lines, "pairs").endswith(f"| 0/{len(config.pairs.seeds)} |")
    assert _row(lines, "benchmark") == f"| benchmark | not run | - | - | 1/{len(config.benchmark.seeds)} unseen |"
    assert _row(lines, "mdi") == "| mdi | not in this config | - | - | - |"


def test_a_running_per_seed_stage_says_about_how_long_is_left_at_its_rate_so_far(tmp_path):
    run = tmp_path / "run"
    config = init_run(run, "carracing", "ci")
    just_now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    # 10 minutes over two calls, one seed of two logged: 10 minutes a seed
    running = {
        "seconds": 240.0,
        "total_seconds": 600.0,
        "finished": just_now,
        "stopped": True,
        "earlier_seconds": 360.0,
    }
    _times(run, benchmark=running)
    _lock(run, os.getpid())
    assert len(config.benchmark.seeds) == 2 and not config.benchmark.confirm_seeds
    RowLog(RunLayout(run).benchmark_log).append({"seed": config.benchmark.seeds[0], "entries": {"bc": []}}, {"bc": {}})
    row = _row(run_status(RunLayout(run), load_run(run)), "benchmark")
    assert re.match(r"\| benchmark \| running \(4 min 0\d s into this call\); about 10 min 0\d s left \|", row), row


def test_a_stage_whose_writer_is_gone_is_stopped_and_resumes(tmp_path):
    run = tmp_path / "run"
    init_run(run, "carracing", "ci")
    gone = subprocess.Popen(["true"])
    gone.wait()
    _lock(run, gone.pid)
    _times(
        run, pistar={"seconds": 30.0, "total_seconds": 30.0, "finished": "2026-01-01T10:05:00+00:00", "stopped": True}
    )
    lines = run_status(RunLayout(run), load_run(run))
    assert lines[1] == "no process writes it now"
    assert _row(lines, "pistar").startswith("| pistar | stopped (resumes) | 30.0 s |")
    assert _row(lines, "pairs").startswith("| pairs | not run | - | - |")


def test_status_of_a_folder_without_a_run_is_one_line(tmp_path):
    result = runner.invoke(app, ["status", "--out", str(tmp_path / "none")])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "config.yaml" in result.output
