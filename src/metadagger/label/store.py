"""A session's labels on disk: each appended durably as it arrives, read back when the session resumes."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from metadagger.errors import CheckpointError
from metadagger.evaluation.benchmark.ledger import LABEL_FIELDS
from metadagger.label.forms import Refused
from metadagger.utils.jsonl import append_line, dumps_line, read_lines


class LabelStore:
    """The labels of one session's ``labels.jsonl``
    (:func:`~metadagger.evaluation.benchmark.ledger.label_record` lines).

    A label is one line appended with flush and fsync before it counts (:mod:`metadagger.utils.jsonl`):
    a label the page was told is kept survives a kill, and a torn last line is no label.

    Args:
        path: the session's ``labels.jsonl`` (read if it exists).
        seed: the session's seed: a line of another seed means the file is not this session's.
    """

    def __init__(self, path: Path, seed: int) -> None:
        self.path = path
        self._lock = threading.Lock()
        self._by_round: dict[int, dict[int, dict[str, Any]]] = {}
        for number, record in enumerate(read_lines(path, called="label record"), start=1):
            if sorted(record) != sorted(LABEL_FIELDS) or record["seed"] != seed:
                raise CheckpointError(
                    f"{path} line {number} is not a label of seed {seed}: {record}; it belongs to another session: "
                    "move it away and run the command again"
                )
            if record["step"] in self._by_round.get(record["round"], {}):
                raise CheckpointError(
                    f"{path} line {number} labels round {record['round']} step {record['step']} a second time; "
                    "delete that line and run the command again"
                )
            self._by_round.setdefault(record["round"], {})[record["step"]] = record

    def given(self, round: int) -> dict[int, dict[str, Any]]:
        """The labels kept for ``round``, by step."""
        with self._lock:
            return dict(self._by_round.get(round, {}))

    def records(self) -> list[dict[str, Any]]:
        """Every label kept, by round and step."""
        with self._lock:
            return [self._by_round[r][s] for r in sorted(self._by_round) for s in sorted(self._by_round[r])]

    def add(self, record: dict[str, Any]) -> None:
        """Keep ``record`` (written to disk before this returns); a step labelled before is :class:`Refused`."""
        with self._lock:
            round, step = record["round"], record["step"]
            if step in self._by_round.get(round, {}):
                raise Refused(f"round {round} step {step} is labelled already: a label is given once", status=409)
            append_line(self.path, dumps_line(record))
            self._by_round.setdefault(round, {})[step] = record
