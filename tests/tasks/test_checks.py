"""The task checker: each mistake in a task's code is one line naming the Task method, the value
seen and what is expected; the packaged tasks pass; check-task measures the expert."""

from __future__ import annotations

import importlib
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from toy_task import CorridorTask, RunCorridorTask
from typer.testing import CliRunner

import metadagger
from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.tasks import _FACTORIES
from metadagger.tasks.checks import check_task_code
from metadagger.tasks.identity import code_fingerprint, task_stamp


def _observations(task: CorridorTask, transform, space: gym.Space) -> None:
    make = type(task).make_base_env
    task.make_base_env = lambda **kw: gym.wrappers.TransformObservation(make(task, **kw), transform, space)


class OneHotExpert(CorridorTask):
    def to_label(self, action):
        return np.eye(3)[int(np.rint(action[0])) + 1]


class FloatLabel(CorridorTask):
    def to_label(self, action):
        return float(np.rint(action[0])) + 1


class OutOfRange(CorridorTask):
    def to_label(self, action):
        return 7


class GlobalRandomRoad(CorridorTask):
    """Draws its road from the global generator, whatever the seed."""

    def make_base_env(self, **kwargs):
        env = super().make_base_env(**kwargs)
        reset = env.reset
        env.reset = lambda *, seed=None, options=None: reset(seed=int(np.random.randint(1 << 30)), options=options)
        return env


class LosesTheLabel(CorridorTask):
    def combine(self, label, action):
        return np.array([0.0], np.float32)


class ReadsMissingState(CorridorTask):
    def expert(self, env):
        return env.unwrapped.state


class BoxShapeMismatch(CorridorTask):
    def __init__(self):
        super().__init__(discrete=False)

    def to_label(self, action):
        return np.zeros(2, np.float32)


class SuccessNotBool(CorridorTask):
    def is_success(self, env):
        return "yes"


@pytest.mark.parametrize(
    "task",
    [
        CorridorTask(),
        CorridorTask(discrete=False),
        metadagger.make_task("carracing"),
        metadagger.make_task("carracing-family"),
    ],
    ids=lambda t: t.name,
)
def test_packaged_and_toy_tasks_pass(task):
    check_task_code(task)


@pytest.mark.parametrize(
    "task, needles",
    [
        (OneHotExpert(), ["OneHotExpert.to_label returned", "shape (3,)", "class index", "int in 0..2"]),
        (FloatLabel(), ["FloatLabel.to_label returned 1.0 (float)", "class index"]),
        (OutOfRange(), ["OutOfRange.to_label returned 7", "0..2"]),
        (GlobalRandomRoad(), ["GlobalRandomRoad.make_base_env", "seed 0 differ", "reset(seed=...)"]),
        (LosesTheLabel(), ["LosesTheLabel.combine and to_label disagree", "expected 0"]),
        (ReadsMissingState(), ["ReadsMissingState.expert raised AttributeError", "'state'"]),
        (BoxShapeMismatch(), ["BoxShapeMismatch.to_label returned float32 of shape (2,)", "shape (1,)"]),
        (SuccessNotBool(), ["SuccessNotBool.is_success returned 'yes'", "bool"]),
    ],
    ids=lambda v: type(v).__name__ if isinstance(v, CorridorTask) else "",
)
def test_each_mistake_is_one_line_naming_the_method(task, needles):
    with pytest.raises(UserError) as info:
        check_task_code(task)
    message = str(info.value)
    assert "\n" not in message
    for needle in needles:
        assert needle in message


@pytest.mark.parametrize(
    "transform, space, needles",
    [
        (
            lambda o: np.moveaxis(o, -1, 0),
            gym.spaces.Box(0, 255, (3, 16, 16), np.uint8),
            ["(3, 16, 16)", "channels-first", "moveaxis"],
        ),
        (
            lambda o: o.astype(np.float32) / 255,
            gym.spaces.Box(0, 1, (16, 16, 3), np.float32),
            ["float32", "uint8", "* 255"],
        ),
        (
            lambda o: o[0, :8].astype(np.float32),
            gym.spaces.Box(-1, 1, (8, 3), np.float32),
            ["(8, 3)", "images (H, W, C)"],
        ),
        (
            lambda o: o.astype(np.float32),
            gym.spaces.Box(0, 255, (16, 16, 3), np.uint8),
            ["reset: returned an observation of float32", "declares uint8"],
        ),
    ],
    ids=["channels-first", "float-image", "state-vector", "space-disagrees"],
)
def test_wrong_observations_are_refused(transform, space, needles):
    task = CorridorTask()
    _observations(task, transform, space)
    with pytest.raises(UserError) as info:
        check_task_code(task)
    for needle in needles:
        assert needle in str(info.value)


def test_a_bad_task_is_refused_before_any_work(tmp_path, monkeypatch):
    """reproduce runs the checks before pi*: nothing is trained on a wrong observation."""
    monkeypatch.setitem(_FACTORIES, "corridor-onehot", OneHotRun)
    presets = tmp_path / "presets.yaml"
    from toy_task import TINY_PRESETS

    presets.write_text(TINY_PRESETS)
    result = CliRunner().invoke(
        app,
        [
            "reproduce",
            "--task",
            "corridor-onehot",
            "--presets",
            str(presets),
            "--preset",
            "tiny",
            "--out",
            str(tmp_path / "run"),
        ],
    )
    assert result.exit_code == 2, result.output
    assert "OneHotRun.to_label returned" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run" / "pistar" / "pistar.safetensors").exists()
    assert not list((tmp_path / "run").glob("pistar/rounds/*"))


class OneHotRun(RunCorridorTask):
    def to_label(self, action):
        return np.eye(3)[int(np.rint(action[0])) + 1]


def test_check_task_measures_the_expert():
    result = CliRunner().invoke(app, ["check-task", "--task", "carracing", "--seeds", "0"])
    assert result.exit_code == 0, result.output
    assert "passes the checks" in result.output and "Discrete(20)" in result.output
    assert "steps per second" in result.output


def test_check_task_of_a_bad_task_is_one_line_exit_2(monkeypatch):
    monkeypatch.setitem(_FACTORIES, "corridor-float-label", FloatLabelRun)
    result = CliRunner().invoke(app, ["check-task", "--task", "corridor-float-label", "--seeds", "0-1"])
    assert result.exit_code == 2
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "FloatLabelRun.to_label returned 1.0" in errors[0]


class FloatLabelRun(RunCorridorTask):
    def to_label(self, action):
        return float(np.rint(action[0])) + 1


TASK_MODULE = """
import numpy as np
from toy_task import RunCorridorTask


class EditedTask(RunCorridorTask):
    name = "edited"

    def expert(self, env):
        return np.array([env.unwrapped.expert_move() * {gain}], dtype=np.float32)
"""


def _edited_task(folder: Path, gain: float) -> type:
    (folder / "edited_task.py").write_text(textwrap.dedent(TASK_MODULE.format(gain=gain)))
    sys.modules.pop("edited_task", None)
    importlib.invalidate_caches()
    return importlib.import_module("edited_task").EditedTask


def test_the_task_code_fingerprint_follows_its_source(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    first = _edited_task(tmp_path, 1.0)
    before = code_fingerprint(first)
    same = _edited_task(tmp_path, 1.0)
    assert code_fingerprint(same) == before
    changed = _edited_task(tmp_path, 0.5)
    assert code_fingerprint(changed) != before
    assert task_stamp(first())["task_code_fingerprint"] == code_fingerprint(first)


def test_a_changed_task_code_makes_its_artifacts_stale(tmp_path, monkeypatch):
    from toy_task import TINY_PRESETS

    monkeypatch.syspath_prepend(str(tmp_path))
    presets = tmp_path / "presets.yaml"
    presets.write_text(TINY_PRESETS)
    args = [
        "pistar",
        "--task",
        "edited",
        "--presets",
        str(presets),
        "--preset",
        "tiny",
        "--out",
        str(tmp_path / "run"),
    ]
    monkeypatch.setitem(_FACTORIES, "edited", _edited_task(tmp_path, 1.0))
    assert CliRunner().invoke(app, args).exit_code == 0
    assert CliRunner().invoke(app, args).exit_code == 0  # unchanged: reused
    monkeypatch.setitem(_FACTORIES, "edited", _edited_task(tmp_path, 0.5))
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert "task_code: changed" in result.output and "Traceback" not in result.output
