"""A run folder of the toy corridor for the labelling sessions: pi*, then the benchmark of the gate they
run (``dagger-safe`` at 0.5 on seed 300), so that a session can be held against the benchmark's row.

The corridor is a task of the test process (``register_task``) and, for a command run in a
process of its own, of an installed package: a distribution's ``dist-info`` folder whose
``entry_points.txt`` names it, on that process's ``PYTHONPATH`` with the tests' folder
(:func:`corridor_session.command`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from corridor_session import PRESETS, TASK

from metadagger.runfolder.layout import RunLayout


@pytest.fixture(scope="package")
def label_run(tmp_path_factory) -> RunLayout:
    """The run folder (pi* and the benchmark's rows); copy it before a session writes in it."""
    from toy_task import RunCorridorTask

    from metadagger.pipeline.run_config import init_run
    from metadagger.pipeline.stages import stage_benchmark, stage_pistar
    from metadagger.runfolder.driver import StageOptions
    from metadagger.tasks import _FACTORIES, register_task

    register_task(TASK, RunCorridorTask)
    folder = tmp_path_factory.mktemp("label-run")
    presets = folder / "presets.yaml"
    presets.write_text(PRESETS)
    layout = RunLayout(folder / "run")
    config = init_run(layout.root, TASK, "label", presets)
    options = StageOptions(executor="inline", progress=False)
    stage_pistar(layout, config, options)
    stage_benchmark(layout, config, options=options)
    yield layout
    del _FACTORIES[TASK]


@pytest.fixture(scope="package")
def corridor_site(tmp_path_factory) -> Path:
    """A folder holding what installing a package with the corridor task writes: its ``dist-info``."""
    site = tmp_path_factory.mktemp("site")
    info = site / "metadagger_corridor_label-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: metadagger-corridor-label\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text(f"[metadagger.tasks]\n{TASK} = toy_task:RunCorridorTask\n")
    return site


@pytest.fixture
def run(label_run, tmp_path) -> RunLayout:
    """A copy of the run folder, for one test's sessions."""
    return RunLayout(shutil.copytree(label_run.root, tmp_path / "run"))
