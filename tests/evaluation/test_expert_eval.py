"""Expert evaluation: episodes driven by the expert's own labels, and the Markdown table."""

from __future__ import annotations

import pytest

import metadagger
from metadagger.evaluation.expert import evaluate_expert, expert_table


def test_expert_completes_laps_with_snapped_steering():
    rows = evaluate_expert(metadagger.make_task("carracing"), [0, 1], progress=False)
    assert [r["seed"] for r in rows] == [0, 1]
    for row in rows:
        assert row["success"] is True
        assert row["steps"] < 1000  # finished (terminated) before the step limit
        assert row["reward"] > 900  # every tile (+1000 in total) minus 0.1 a step


def test_short_step_limit_truncates_without_success():
    [row] = evaluate_expert(metadagger.make_task("carracing", max_episode_steps=10), [3], progress=False)
    assert (row["seed"], row["success"], row["steps"]) == (3, False, 10)
    assert row["reward"] < 100  # a few tiles at most


def test_episodes_are_deterministic():
    task = metadagger.make_task("carracing", max_episode_steps=60)
    assert evaluate_expert(task, [5], progress=False) == evaluate_expert(task, [5], progress=False)


def test_expert_table():
    rows = [
        {"seed": 0, "success": True, "reward": 900.0, "steps": 800},
        {"seed": 1, "success": False, "reward": 700.0, "steps": 1000},
    ]
    lines = expert_table(rows).splitlines()
    assert lines[0] == "| episodes | successes | success rate | mean reward | episode steps (min / mean / max) |"
    assert lines[2] == "| 2 | 1 | 50.0% (9%-91%) | 800.0 | 800 / 900.0 / 1000 |"
    timed = expert_table(rows, seconds=4.5).splitlines()
    assert timed[0].endswith("| steps per second |") and timed[2].endswith("| 400 |")


def test_expert_table_needs_rows():
    with pytest.raises(ValueError, match="at least one row"):
        expert_table([])
