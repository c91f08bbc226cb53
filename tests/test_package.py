"""Importing metadagger changes nothing a caller did not ask for; making a task registers the ids."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = (
    "import os, gymnasium as gym, metadagger; "
    "print('ATEN_CPU_CAPABILITY' in os.environ, 'ONEDNN_MAX_CPU_ISA' in os.environ, "
    "any(i.startswith('metadagger/') for i in gym.registry)); "
    "metadagger.make_task('carracing'); print('metadagger/CarRacingSteer-v0' in gym.registry)"
)


def test_import_leaves_the_environment_and_the_gym_registry_alone_until_a_task_is_made():
    clean = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA")}
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=clean, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["False", "False", "False", "True"]
