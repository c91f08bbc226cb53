"""The query ledger: which states each benchmark row's chain asked the expert about, and how.

A benchmark row counts its expert queries (labelled states) and, from the same record, two more
ways the field counts them: **takeovers**, maximal runs of consecutive labelled steps within one
episode (each a context switch for the expert, as LazyDAgger counts them), and **episodes asked**,
the episodes with at least one label. The demonstration is round 0: one episode, one takeover, all
of its steps. A row keeps its record (:func:`round_record` per round) under ``labels``; the run's
``benchmark/labels.jsonl`` holds one line per row and round (:func:`ledger_lines`), so a reader
can audit a gate's choices without running it again. docs/benchmark.md lists the columns.

Where a person is the expert (``metadagger label``, docs/label.md), each label is also a
:func:`label_record`: the step it answers, the label, the seconds from the state's showing to the
answer, who answered (:data:`PERSON` or :data:`SCRIPTED`) and whether it began a takeover (a
switch of the person's attention to the learner's episode).
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

#: Who answered a label: a person at the labelling page, or the task's scripted expert.
PERSON, SCRIPTED = "person", "scripted"
#: Fields of a line of a labelling session's ``labels.jsonl``.
LABEL_FIELDS = ("seed", "round", "step", "label", "seconds", "who", "switch")


def step_runs(asked: np.ndarray) -> list[list[int]]:
    """Ascending step indices as maximal runs of consecutive steps, ``[[start, stop), ...]``."""
    asked = np.asarray(asked, dtype=np.int64)
    if len(asked) == 0:
        return []
    breaks = np.flatnonzero(np.diff(asked) != 1) + 1
    starts = np.concatenate([[0], breaks])
    stops = np.concatenate([breaks, [len(asked)]])
    return [[int(asked[a]), int(asked[b - 1]) + 1] for a, b in zip(starts, stops)]


def round_record(index: int, asked: np.ndarray, scores: np.ndarray | None) -> dict[str, Any]:
    """One round's labelled steps as runs, with the gate's scores at them (6 significant digits) or None."""
    if scores is not None and len(scores) != len(asked):
        raise ValueError(f"round {index}: {len(scores)} scores for {len(asked)} labelled steps")
    return {
        "round": int(index),
        "runs": step_runs(asked),
        "scores": None if scores is None else [float(f"{float(x):.6g}") for x in scores],
    }


def demonstration_record(steps: int) -> dict[str, Any]:
    """Round 0: the expert drove all ``steps`` steps of one episode."""
    return round_record(0, np.arange(steps), None)


def tally(records: Iterable[dict[str, Any]]) -> dict[str, int]:
    """A row's ``takeovers`` and ``episodes_asked`` from its rounds' records."""
    records = list(records)
    return {
        "takeovers": sum(len(r["runs"]) for r in records),
        "episodes_asked": sum(1 for r in records if r["runs"]),
    }


def ledger_lines(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """One line per row and round of ``rows`` (each with its ``labels`` records), in row order."""
    return [
        {
            "method": r["method"],
            "setting": r["setting"],
            "demo_fraction": r["demo_fraction"],
            "seed": r["seed"],
            **record,
        }
        for r in rows
        for record in r.get("labels", [])
    ]


def label_record(
    seed: int, round: int, step: int, label: int | list[float], seconds: float, who: str, switch: bool
) -> dict[str, Any]:
    """One label as a session's ``labels.jsonl`` keeps it (:data:`LABEL_FIELDS`); ``seconds`` to the millisecond.

    Args:
        seed: the env seed of the episode.
        round: the DAgger round (1-based).
        step: the labelled step of the round's rollout.
        label: a class index, or the action vector.
        seconds: from the state's showing to the answer (0 for the scripted expert).
        who: :data:`PERSON` or :data:`SCRIPTED`.
        switch: whether the step begins a takeover (the step before it was not asked).
    """
    if who not in (PERSON, SCRIPTED):
        raise ValueError(f"who must be {PERSON!r} or {SCRIPTED!r}, got {who!r}")
    return {
        "seed": int(seed),
        "round": int(round),
        "step": int(step),
        "label": label,
        "seconds": round_seconds(seconds),
        "who": who,
        "switch": bool(switch),
    }


def round_seconds(seconds: float) -> float:
    """Seconds as the ledger keeps them: to the millisecond."""
    return float(f"{float(seconds):.3f}")


def effort(records: Iterable[dict[str, Any]], round: int) -> dict[str, Any]:
    """What rounds 1..``round`` of a session's label records cost the one who answered: ``labels``, ``seconds``
    (their sum), ``switches`` (takeovers begun) and ``labelled_by`` (who answered: ``person``,
    ``scripted``, or both joined by ``+``; ``-`` where no label was given)."""
    mine = [r for r in records if r["round"] <= round]
    who = sorted({r["who"] for r in mine})
    return {
        "labels": len(mine),
        "seconds": round_seconds(sum(r["seconds"] for r in mine)),
        "switches": sum(1 for r in mine if r["switch"]),
        "labelled_by": "+".join(who) if who else "-",
    }
