"""One writer per run folder: an advisory lock held while a stage writes.

A stage that writes to a run folder holds an exclusive ``flock`` on ``RUN/.lock`` for as long as
it runs; the file says who holds it (pid, host, command, since when). A second writer is refused
at once with one line naming the holder. The kernel drops the lock when its process ends, however
it ends (``kill -9`` included), so a lock left by a killed process is simply taken by the next
writer; that writer then removes the temporary files the killed one left (``.*.tmp``: an
artifact is only ever written to such a file and renamed into place). Readers (``report``,
``config show``) take no lock. The lock is re-entrant within a process: ``reproduce`` holds it
around the stages it runs, each of which asks for it again.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from metadagger.errors import UserError
from metadagger.utils.io import make_folder

#: The lock file's name in a run folder.
LOCK_FILE = ".lock"

# run folder (resolved) -> [open lock file, depth]: this process's held locks
_held: dict[Path, list] = {}


@contextmanager
def run_lock(root: str | Path, command: str | None = None) -> Iterator[None]:
    """Hold the write lock of run folder ``root`` (created if missing) for the ``with`` block.

    Args:
        root: the run folder.
        command: what this writer runs, for the message a refused writer gets (default: this
            process's command line).

    Raises:
        UserError: another process holds the lock, or the folder cannot hold a lock file (its
            message names the path and what to do).
    """
    root = Path(root)
    key = root.resolve()
    if key in _held:
        _held[key][1] += 1
        try:
            yield
        finally:
            _held[key][1] -= 1
        return
    handle = _acquire(root, command or " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]))
    _held[key] = [handle, 1]
    try:
        remove_temporary_files(root)
        yield
    finally:
        del _held[key]
        handle.close()  # releases the lock; the file stays (removing it would race a waiting writer)


def _acquire(root: Path, command: str):
    path = root / LOCK_FILE
    make_folder(root)
    try:
        handle = open(path, "a+", encoding="utf-8")
    except OSError as exc:
        raise UserError(
            f"cannot write the run folder {root} ({exc.strerror}): {path} cannot be created; "
            "choose a folder you can write to (--out) or fix its permissions"
        ) from None
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = _describe(handle.read())
        handle.close()
        raise UserError(
            f"run folder {root} is in use by {holder}; wait for it to finish (or stop it), "
            "or write to another folder with --out"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(
        json.dumps(
            {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "command": command,
                "since": time.strftime("%Y-%m-%d %H:%M:%S"),
            }
        )
    )
    handle.flush()
    return handle


def _describe(text: str) -> str:
    try:
        holder = json.loads(text)
        return f"pid {holder['pid']} on {holder['host']} (`{holder['command']}`, since {holder['since']})"
    except (ValueError, KeyError, TypeError):
        return "another process"


def remove_temporary_files(root: str | Path) -> list[Path]:
    """Remove the temporary files and folders (``.*.tmp``, ``.*.tmp.old``) under ``root`` that a
    killed writer left; only the lock's holder may call this. Returns what was removed."""
    root = Path(root)
    removed = [path for pattern in (".*.tmp", ".*.tmp.old") for path in root.rglob(pattern)]
    for path in removed:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return removed


def holds_lock(root: str | Path) -> bool:
    """Whether this process holds the write lock of ``root``."""
    return Path(root).resolve() in _held
