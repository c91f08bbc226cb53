"""The worked example examples/lunarlander: its task, its entry point and its ``ci`` preset end to end.

The example is a package of its own (installed with ``pip install -e examples/lunarlander``); the
tests do not install it, they put its source folder on ``sys.path`` (the worker processes inherit
it) and register the task as the entry point would.
"""

from __future__ import annotations

import json
import pickle
import tomllib
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import metadagger
import metadagger.tasks as tasks
from metadagger.cli.main import app
from metadagger.evaluation.rows import read_csv

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lunarlander"
runner = CliRunner()


@pytest.fixture
def task_class(monkeypatch):
    """The example's task classes, registered as ``lunarlander`` and ``lunarlander-all`` for this test only."""
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    from metadagger_lunarlander.task import LunarLanderAllEnginesTask, LunarLanderTask

    metadagger.register_task("lunarlander", LunarLanderTask)
    metadagger.register_task("lunarlander-all", LunarLanderAllEnginesTask)
    yield LunarLanderTask
    tasks._FACTORIES.pop("lunarlander", None)
    tasks._FACTORIES.pop("lunarlander-all", None)


def test_the_entry_points_name_the_task_classes(task_class):
    pyproject = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())
    entry_points = pyproject["project"]["entry-points"][tasks.ENTRY_POINT_GROUP]
    assert set(entry_points) == {"lunarlander", "lunarlander-all"}
    for name, value in entry_points.items():
        loaded = EntryPoint(name=name, value=value, group=tasks.ENTRY_POINT_GROUP).load()
        assert loaded.name == name and issubclass(loaded, task_class)
    assert entry_points["lunarlander"] == "metadagger_lunarlander.task:LunarLanderTask"
    assert "metadagger" in pyproject["project"]["dependencies"]


def test_the_task_is_pixels_with_the_heuristic_as_expert(task_class):
    task = metadagger.make_task("lunarlander", max_episode_steps=400)
    assert isinstance(task, task_class) and task.max_episode_steps == 400
    pickle.loads(pickle.dumps(task))  # sent to the workers
    env = task.make_env()
    assert env.observation_space.shape == (64, 96, 3) and env.observation_space.dtype == np.uint8
    assert task.is_discrete and task.label_dim() == 2
    obs, info = env.reset(seed=0)
    first = obs.copy()
    steps = 0
    upstream_actions = set()
    while True:
        assert env.observation_space.contains(obs)
        label, action = info["expert_label"], info["expert_action"]
        assert isinstance(label, int) and task.combine(label, action) == int(action[0])  # the heuristic's own action
        upstream_actions.add(int(action[0]))
        obs, _, terminated, truncated, info = env.step(label)
        steps += 1
        if terminated or truncated:
            break
    assert terminated and info["is_success"] and steps < 400
    assert upstream_actions == {0, 1, 2, 3}
    np.testing.assert_array_equal(env.reset(seed=0)[0], first)
    side, main = np.array([1.0], np.float32), np.array([2.0], np.float32)
    assert (task.combine(1, side), task.combine(0, side), task.combine(0, main)) == (2, 1, 0)
    with pytest.raises(ValueError, match="0 or 1"):
        task.combine(2, side)
    every_engine = metadagger.make_task("lunarlander-all")
    assert every_engine.label_dim() == 4 and every_engine.combine(3, main) == 3 and every_engine.to_label(side) == 1


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_ci_preset_runs_every_stage(task_class, tmp_path):
    run = tmp_path / "run"
    args = [
        "reproduce",
        "--task",
        "lunarlander",
        "--presets",
        str(EXAMPLE / "presets.yaml"),
        "--preset",
        "ci",
        "--out",
        str(run),
        "--workers",
        "2",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert (run / "pistar" / "policy.safetensors").is_file()
    assert json.loads((run / "pairs" / "summary.json").read_text())["seeds"] == 4
    assert {r["method"] for r in read_csv(run / "eval" / "mdm.csv")} >= {"bc", "dm", "ridge", "mean-da", "pistar-head"}
    assert (run / "benchmark" / "summary.json").is_file()
    assert "Table 1" in (run / "report" / "report.md").read_text()
