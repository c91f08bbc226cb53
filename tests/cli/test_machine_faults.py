"""The machine's faults on a real file system: a full disk and a read-only run folder are one
error line naming the path and what to do, exit 2, finished work kept. Needs a machine where the
tests may mount a small tmpfs (root on Linux); skipped elsewhere."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from toy_task import TINY_PRESETS, RunCorridorTask
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.tasks import _FACTORIES

runner = CliRunner()


@pytest.fixture
def tmpfs(tmp_path):
    """A folder on its own small file system: ``remount(options)`` changes its size or makes it read-only."""
    folder = tmp_path / "fs"
    folder.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)], capture_output=True).returncode:
        pytest.skip("this machine does not let the tests mount a tmpfs")

    def remount(options: str) -> None:
        subprocess.run(["mount", "-o", f"remount,{options}", str(folder)], check=True)

    yield folder, remount
    subprocess.run(["umount", str(folder)], check=True)


def _reproduce(run: Path, presets: Path):
    return runner.invoke(
        app,
        [
            "reproduce",
            "--task",
            "corridor-run",
            "--presets",
            str(presets),
            "--preset",
            "tiny",
            "--out",
            str(run),
            "--workers",
            "1",
        ],
    )


def _one_error_line(output: str, *needles: str) -> None:
    assert "Traceback" not in output, output
    errors = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, output
    for needle in needles:
        assert needle.lower() in errors[0].lower(), errors[0]


def test_a_full_disk_and_a_read_only_folder_are_one_line_and_keep_finished_work(tmpfs, tmp_path, monkeypatch):
    folder, remount = tmpfs
    monkeypatch.setitem(_FACTORIES, "corridor-run", RunCorridorTask)
    presets = tmp_path / "presets.yaml"
    presets.write_text(TINY_PRESETS)
    run = folder / "run"

    full = _reproduce(run, presets)
    assert full.exit_code == 2
    _one_error_line(full.output, "the disk is full", "free some space")
    kept = {p: p.read_bytes() for p in run.rglob("*.safetensors")}
    assert kept, "the stages before the full disk kept their work"

    remount("size=64m")
    done = _reproduce(run, presets)
    assert done.exit_code == 0, done.output
    assert all(p.read_bytes() == data for p, data in kept.items())  # resumed, not redone
    assert not [p for p in run.rglob("*.tmp")]

    remount("ro")
    for args in (
        ["report", "--out", str(run)],
        ["evaluate", "--out", str(run), "--seeds", "400-401"],
        ["train-mapper", "--out", str(run), "--kind", "dm", "--rebuild"],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        _one_error_line(result.output, str(run), "read-only")
