"""The per-seed driver's row log: rows by stamp, and a line without entries is a corrupt line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from metadagger.errors import CheckpointError
from metadagger.runfolder.driver import RowLog


def test_a_row_record_without_entries_is_a_corrupt_line(tmp_path: Path) -> None:
    log = RowLog(tmp_path / "eval" / "rows.jsonl")
    log.append({"seed": 1, "entries": {"bc": [{"seed": 1, "success": True}]}}, {"bc": {"rounds": 1}})
    assert log.stamps() == {1: {"bc": {"rounds": 1}}}
    assert log.rows([1], {"bc": {"rounds": 1}}) == [{"seed": 1, "success": True}]
    with open(log.path, "ab") as f:
        f.write(b'{"seed": 2, "rows": []}\n')
    with pytest.raises(
        CheckpointError,
        match=re.escape(f"{log.path} has a row record without its entries: ")
        + ".*"
        + re.escape("; delete that line and re-run the stage")
        + "$",
    ):
        log.stamps()
