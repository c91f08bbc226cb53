"""A stage's wall time in ``stage_times.json``: written while it runs, so a call killed without a
word (SIGKILL, a machine that stops) still counts, and added up over the calls of a resumed run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from metadagger.errors import UserError
from metadagger.pipeline import stage_runs
from metadagger.pipeline.run_config import load_run
from metadagger.pipeline.stage_runs import records_config
from metadagger.pipeline.stages import init_run
from metadagger.runfolder.layout import RunLayout


def _entry(run, stage="sleep"):
    return json.loads((run / "stage_times.json").read_text())[stage]


@records_config
def stage_sleep(layout, config, seconds, seen=None, refuse=False):
    if refuse:
        raise UserError("refused")
    time.sleep(seconds)
    if seen is not None:  # what a reader finds while the stage runs
        seen.append(_entry(layout.root))


def test_a_running_stage_writes_its_time_so_far_and_its_finished_call_adds_up(tmp_path, monkeypatch):
    run = tmp_path / "run"
    init_run(run, "carracing", "ci")
    monkeypatch.setattr(stage_runs, "HEARTBEAT_SECONDS", 0.05)
    seen = []
    stage_sleep(RunLayout(run), load_run(run), 0.4, seen)
    (during,) = seen
    assert during["stopped"] is True and during["earlier_seconds"] == 0
    assert 0.2 <= during["seconds"] == during["total_seconds"] <= 0.4
    first = _entry(run)
    assert "stopped" not in first and "earlier_seconds" not in first
    assert first["total_seconds"] == first["seconds"] >= 0.4

    stage_sleep(RunLayout(run), load_run(run), 0.2, seen)
    assert seen[-1]["earlier_seconds"] == first["total_seconds"]
    again = _entry(run)
    assert again["total_seconds"] == pytest.approx(first["total_seconds"] + again["seconds"], abs=2e-3)


def test_a_refused_call_counts_no_time(tmp_path):
    run = tmp_path / "run"
    init_run(run, "carracing", "ci")
    with pytest.raises(UserError):
        stage_sleep(RunLayout(run), load_run(run), 0.0, refuse=True)
    assert not (run / "stage_times.json").exists()
    stage_sleep(RunLayout(run), load_run(run), 0.0)
    before = _entry(run)
    with pytest.raises(UserError):
        stage_sleep(RunLayout(run), load_run(run), 0.0, refuse=True)
    assert _entry(run) == before


KILLED = """
import sys, time
from metadagger.pipeline import stage_runs
from metadagger.pipeline.run_config import load_run
from metadagger.runfolder.layout import RunLayout
stage_runs.HEARTBEAT_SECONDS = 0.05

@stage_runs.records_config
def stage_sleep(layout, config):
    print("started", flush=True)
    time.sleep(60)

stage_sleep(RunLayout(sys.argv[1]), load_run(sys.argv[1]))
"""


def test_a_call_killed_without_a_word_keeps_the_time_it_ran(tmp_path):
    run = tmp_path / "run"
    init_run(run, "carracing", "ci")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    child = subprocess.Popen([sys.executable, "-c", KILLED, str(run)], stdout=subprocess.PIPE, text=True, env=env)
    assert child.stdout.readline().strip() == "started"
    time.sleep(0.5)
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=30)
    killed = _entry(run)
    assert killed["stopped"] is True and killed["seconds"] >= 0.3

    stage_sleep(RunLayout(run), load_run(run), 0.0)
    resumed = _entry(run)
    assert "stopped" not in resumed
    assert resumed["total_seconds"] == pytest.approx(killed["total_seconds"] + resumed["seconds"], abs=2e-3)
