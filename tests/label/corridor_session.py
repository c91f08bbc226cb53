"""The labelling tests' run: its presets, the session they label, and the command in a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
#: The task's name in the run's config, as the test process and the command's process know it.
TASK = "corridor-label"
#: The session the tests run: the gate, its setting, the seed.
GATE, SETTING, SEED = "safe", 0.5, 300
PRESETS = """\
presets:
  label:
    max_episode_steps: 30
    pistar:
      seeds: 0-3
      eval_seeds: 100-100
      min_success: 0.0
      dagger_rounds: 1
      bc: {lr: 3.0e-3, batch_size: 16, epochs: 3}
    pairs:
      seeds: 200-203
      dagger_rounds: 3
      keep: all
      bc: {lr: 1.0e-2, batch_size: 10, epochs: 1, head_only: true}
      dagger_bc: {lr: 1.0e-2, batch_size: 10, epochs: 1, head_only: true}
    evaluate: {seeds: 300-301, methods: [dm], oneshot: false}
    benchmark:
      seeds: [300]
      methods: [dagger-safe]
      grids: {dagger-safe: [0.5]}
      oracle: false
"""


def command(site: Path, *args: str) -> subprocess.Popen:
    """``metadagger ARGS`` started in a process of its own that sees the corridor task (stdout piped, as text)."""
    path = os.pathsep.join([str(site), str(TESTS), os.environ.get("PYTHONPATH", "")])
    return subprocess.Popen(
        [sys.executable, "-u", "-m", "metadagger.cli", *args],
        env={**os.environ, "PYTHONPATH": path},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def session_args(run: Path, *more: str) -> list[str]:
    """The command line of the tests' session on ``run``."""
    return ["label", "--out", str(run), "--seed", str(SEED), "--gate", GATE, "--setting", str(SETTING), *more]
