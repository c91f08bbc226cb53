"""Atomic folders: built aside, swapped in whole; a failure leaves the old folder as it was."""

from __future__ import annotations

import stat

import pytest

from metadagger.utils.io import atomic_folder


def _write(files: dict[str, str]):
    def write(folder):
        for name, text in files.items():
            (folder / name).write_text(text)

    return write


def test_a_folder_is_replaced_whole_and_no_staging_is_left(tmp_path):
    target = tmp_path / "out" / "ns"
    atomic_folder(target, _write({"a": "1", "b": "2"}), staging_in=tmp_path)
    atomic_folder(target, _write({"c": "3"}), staging_in=tmp_path)
    assert sorted(p.name for p in target.iterdir()) == ["c"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_folder_has_the_mode_the_umask_gives_a_new_folder(tmp_path):
    target = atomic_folder(tmp_path / "ns", _write({"a": "1"}))
    (tmp_path / "plain").mkdir()
    assert stat.S_IMODE(target.stat().st_mode) == stat.S_IMODE((tmp_path / "plain").stat().st_mode)


def test_a_failed_write_leaves_the_old_folder(tmp_path):
    target = tmp_path / "ns"
    atomic_folder(target, _write({"a": "1"}))

    def fail(folder):
        (folder / "half").write_text("x")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError, match="killed"):
        atomic_folder(target, fail)
    assert [p.name for p in target.iterdir()] == ["a"] and (target / "a").read_text() == "1"
    assert [p.name for p in tmp_path.iterdir()] == ["ns"]
