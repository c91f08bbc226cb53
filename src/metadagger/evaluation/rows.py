"""Evaluation rows as CSV tables (written from the resume logs of :mod:`metadagger.runfolder.driver`)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from metadagger.utils.io import corrupt_artifact, write_text

ROW_FIELDS = ("method", "seed", "success", "reward", "steps", "expert_queries")
#: The columns every mapper's ``curves.csv`` has (its other columns are losses).
CURVE_COLUMNS = ("model", "epoch")


def write_csv(path: str | Path, rows: list[dict[str, Any]], fields: tuple[str, ...] = ROW_FIELDS) -> Path:
    """Write rows as CSV atomically (header only when there are none)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fields), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, buf.getvalue())


def read_csv(path: str | Path, columns: tuple[str, ...] = ROW_FIELDS[:2]) -> list[dict[str, Any]]:
    """Rows of a CSV written by :func:`write_csv`, with numbers and booleans parsed back; a table
    without the ``columns`` its readers need is a :class:`~metadagger.errors.UserError`."""
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in columns if c not in (reader.fieldnames or ())]
            if missing:
                raise corrupt_artifact("the table", path, f"no column {', '.join(missing)}")
            return [_parse(row) for row in reader]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise corrupt_artifact("the table", path, str(exc)) from None


def _parse(row: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in row.items():
        if value in ("True", "False"):
            out[key] = value == "True"
        else:
            try:
                out[key] = int(value)
            except ValueError:
                try:
                    out[key] = float(value)
                except ValueError:
                    out[key] = value
    return out
