"""Evaluation rows on disk: a per-seed JSONL log (resumable) and the CSV tables built from it."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from metadagger.io import write_text
from metadagger.jsonl import append_line, dumps_line, read_lines

ROW_FIELDS = ("method", "seed", "success", "reward", "steps", "expert_queries")


class RowLog:
    """``rows.jsonl``: one line per evaluated seed holding all of that seed's rows."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def append(self, seed: int, rows: list[dict[str, Any]]) -> None:
        """Record a finished seed (only the driver writes)."""
        append_line(self.path, dumps_line({"seed": int(seed), "rows": rows}))

    def _latest(self) -> dict[int, list[dict[str, Any]]]:
        return {int(r["seed"]): r["rows"] for r in read_lines(self.path, what="row record")}

    def done_seeds(self, methods: tuple[str, ...] | None = None) -> set[int]:
        """Seeds already evaluated (with a row for each of ``methods``, when given)."""
        latest = self._latest()
        if methods is None:
            return set(latest)
        return {seed for seed, rows in latest.items() if set(methods) <= {row["method"] for row in rows}}

    def rows(self) -> list[dict[str, Any]]:
        """Every row, by seed then in evaluation order (a seed's last record wins)."""
        latest = self._latest()
        return [row for seed in sorted(latest) for row in latest[seed]]


def write_csv(path: str | Path, rows: list[dict[str, Any]], fields: tuple[str, ...] = ROW_FIELDS) -> Path:
    """Write rows as CSV atomically (header only when there are none)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fields), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, buf.getvalue())


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a CSV written by :func:`write_csv`, with numbers and booleans parsed back."""
    with open(path, newline="") as f:
        return [_parse(row) for row in csv.DictReader(f)]


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
