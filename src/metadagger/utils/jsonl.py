"""Append-only JSON-lines logs that survive SIGKILL: each record is one line, appended with
flush + fsync; a torn last line (a kill mid-append) is ignored when read and cut off by the next
append, so a record is either fully there or not there at all."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable

from metadagger.errors import CheckpointError
from metadagger.utils.io import atomic_write


def append_line(path: str | Path, line: bytes) -> None:
    """Append one newline-terminated JSON line durably (dropping a torn tail first)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as f:
        _cut_torn_tail(f)
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def dumps_line(record: dict[str, Any]) -> bytes:
    """A record as one JSON line with sorted keys (identical records give identical bytes)."""
    return (json.dumps(record, sort_keys=True, separators=(",", ":")) + "\n").encode()


def write_lines(path: str | Path, records: Iterable[dict[str, Any]]) -> Path:
    """Write ``records`` as a whole JSON-lines file at once, atomically (:func:`dumps_line` each)."""
    return atomic_write(path, lambda tmp: tmp.write_bytes(b"".join(dumps_line(r) for r in records)))


def read_lines(path: str | Path, *, called: str) -> list[dict[str, Any]]:
    """Every complete record of a log (none if it does not exist); a garbled complete line is a
    :class:`CheckpointError` naming the file and line."""
    path = Path(path)
    if not path.is_file():
        return []
    data = path.read_bytes()
    complete = data[: data.rfind(b"\n") + 1]  # after the last newline: a torn append
    records = []
    for number, raw in enumerate(complete.splitlines(), start=1):
        if not raw.strip():
            continue
        try:
            record = json.loads(raw)
        except ValueError:
            record = None
        if not isinstance(record, dict):
            raise CheckpointError(
                f"{path} line {number} is not a {called}: {raw[:80]!r}; delete that line and re-run the stage"
            )
        records.append(record)
    return records


def _cut_torn_tail(f: Any) -> None:
    """Truncate a file opened ``a+b`` after its last newline (drops a torn last line)."""
    size = f.seek(0, os.SEEK_END)
    if size == 0:
        return
    f.seek(size - 1)
    if f.read(1) == b"\n":
        return
    f.seek(0)
    data = f.read()
    f.truncate(data.rfind(b"\n") + 1)
