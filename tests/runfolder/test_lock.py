"""One writer per run folder: a second writer is refused, a killed one's lock and temporary files are taken over."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from metadagger.errors import UserError
from metadagger.runfolder.lock import holds_lock, run_lock

HOLDER = textwrap.dedent("""
    import sys, time
    from metadagger.runfolder.lock import run_lock
    with run_lock(sys.argv[1], command="metadagger pairs --out RUN"):
        print("held", flush=True)
        time.sleep(60)
""")


def _hold(run) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_second_writer_is_refused_with_one_line_naming_the_holder(tmp_path):
    holder = _hold(tmp_path)
    try:
        started = time.monotonic()
        with pytest.raises(
            UserError,
            match=rf"run folder {tmp_path} is in use by pid {holder.pid} on .* "
            r"\(`metadagger pairs --out RUN`, since .*\); wait for it to finish",
        ):
            with run_lock(tmp_path):
                pass
        assert time.monotonic() - started < 1.0
    finally:
        holder.kill()
        holder.wait()


def test_the_lock_of_a_killed_writer_is_taken_and_its_temporary_files_removed(tmp_path):
    holder = _hold(tmp_path)
    (tmp_path / "mappers" / "tam").mkdir(parents=True)
    left = tmp_path / "mappers" / "tam" / ".mapper.safetensors.abc123.tmp"
    left.write_bytes(b"")
    kept = tmp_path / "mappers" / "tam" / "mapper.safetensors"
    kept.write_bytes(b"finished")
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    with run_lock(tmp_path):
        assert holds_lock(tmp_path)
        assert not left.exists() and kept.read_bytes() == b"finished"
    assert not holds_lock(tmp_path)


def test_the_lock_is_reentrant_in_one_process(tmp_path):
    with run_lock(tmp_path):
        with run_lock(tmp_path):
            assert holds_lock(tmp_path)
        assert holds_lock(tmp_path)
    assert not holds_lock(tmp_path)


def test_a_folder_that_cannot_hold_the_lock_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(UserError, match="cannot create folder .*is a file, not a folder"):
        with run_lock(blocker / "run"):
            pass
