"""The machine's cache of finished artifacts: where it lives, what it takes back, what it refuses."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from metadagger.runfolder import machine_cache
from metadagger.runfolder.machine_cache import CACHE_ENV, cache_root, cached, entry_folder, keep, made_record

STAMP = {"task": "corridor", "epochs": 3, "seeds": [0, 1, 2]}


@pytest.fixture(autouse=True)
def committed(monkeypatch) -> None:
    """Every test runs as from a commit, whatever the tree it is run from."""
    monkeypatch.setattr(machine_cache, "source_revision", lambda: "0123abc")


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def artifact(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def test_the_cache_lives_where_the_environment_says_and_can_be_turned_off(tmp_path, monkeypatch):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root() == tmp_path / "xdg" / "metadagger"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_root() == tmp_path / "home" / ".cache" / "metadagger"
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "mine"))
    assert cache_root() == tmp_path / "mine"
    monkeypatch.setattr(machine_cache, "source_revision", lambda: "0123abc+dirty")  # code being changed
    assert cache_root() is None
    monkeypatch.setattr(machine_cache, "source_revision", lambda: "")  # installed, not a checkout
    assert cache_root() == tmp_path / "mine"
    monkeypatch.setenv(CACHE_ENV, "OFF")
    assert cache_root() is None and entry_folder("pistar", STAMP) is None
    assert keep("pistar", STAMP, {"a.bin": artifact(tmp_path, "a.bin", b"1")}, {"run": "r"}) is None
    assert cached("pistar", STAMP, ("a.bin",)) is None


def test_an_entry_gives_back_its_files_under_its_own_stamp_alone(cache, tmp_path):
    files = {"a.bin": artifact(tmp_path, "a.bin", b"weights"), "m.json": artifact(tmp_path, "m.json", b"{}")}
    entry = keep("pistar", STAMP, files, {"run": "/runs/one", "seconds": 12.5})
    assert entry is not None and entry.parent == cache / "pistar"
    assert cached("pistar", dict(reversed(list(STAMP.items()))), ("a.bin", "m.json")) == entry  # key order is moot
    assert (entry / "a.bin").read_bytes() == b"weights" and made_record(entry)["seconds"] == 12.5
    assert cached("pistar", {**STAMP, "epochs": 4}, ("a.bin",)) is None
    assert cached("pistar", STAMP, ("a.bin", "missing.bin")) is None
    # a second run keeping the same artifact leaves the first entry as it is
    keep("pistar", STAMP, {"a.bin": artifact(tmp_path, "b.bin", b"other"), "m.json": files["m.json"]}, {"run": "two"})
    assert (entry / "a.bin").read_bytes() == b"weights" and made_record(entry)["run"] == "/runs/one"
    assert not [p for p in (cache / "pistar").iterdir() if p != entry]  # no staging folder left behind


def test_an_entry_that_does_not_read_is_passed_over_and_written_again(cache, tmp_path):
    files = {"a.bin": artifact(tmp_path, "a.bin", b"weights")}
    entry = keep("pistar", STAMP, files, {"run": "one"})
    (entry / machine_cache.STAMP_FILE).write_text('{"task": "corr')
    assert cached("pistar", STAMP, ("a.bin",)) is None
    assert keep("pistar", STAMP, files, {"run": "two"}) == entry
    assert cached("pistar", STAMP, ("a.bin",)) == entry and made_record(entry)["run"] == "two"
    # an entry under this key with another stamp (a collision, or a hand-made folder) is never taken
    (entry / machine_cache.STAMP_FILE).write_text(json.dumps({**STAMP, "epochs": 9}))
    assert cached("pistar", STAMP, ("a.bin",)) is None


def test_a_cache_that_cannot_be_written_is_a_warning_and_the_run_goes_on(tmp_path, monkeypatch, capsys):
    blocker = artifact(tmp_path, "blocker", b"a file where the cache's folder would be")
    monkeypatch.setenv(CACHE_ENV, str(blocker / "cache"))
    assert keep("pistar", STAMP, {"a.bin": artifact(tmp_path, "a.bin", b"1")}, {"run": "r"}) is None
    warning = capsys.readouterr().err.strip()
    assert warning.startswith("warning: could not keep pistar in the cache") and f"{CACHE_ENV}=off" in warning
    assert len(warning.splitlines()) == 1
