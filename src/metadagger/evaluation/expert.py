"""Measure a task's expert: drive the learner env with the expert's own labels, one episode a seed.

Driving with ``info["expert_label"]`` (not the expert's full action) measures the expert as the
learner sees it: for CarRacing that is the steering snapped to the 20 classes.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.tasks.base import Task
from metadagger.version import source_revision


def evaluate_expert(task: Task, seeds: Iterable[int], *, progress: bool = True) -> list[dict[str, Any]]:
    """One row per seed (``seed``, ``success``, ``reward``, ``steps``), the expert acting."""
    return evaluate_policy(task, None, list(seeds), label=f"expert {task.name}", progress=progress)


def expert_record(
    task: str,
    preset: str | None,
    task_kwargs: dict[str, Any],
    seeds: str,
    rows: list[dict[str, Any]],
    presets: str | None = None,
) -> dict[str, Any]:
    """What ``metadagger expert --out`` keeps: the task, the preset it was built as (None: its own
    defaults; from the file ``presets`` where given) with the keyword arguments that gave, the
    seeds as given, the per-seed rows, the command that makes it again and the source revision."""
    flag = ("" if presets is None else f" --presets {presets}") + ("" if preset is None else f" --preset {preset}")
    return {
        "task": task,
        "preset": preset,
        "task_kwargs": dict(task_kwargs),
        "seeds": seeds,
        "rows": rows,
        "command": f"metadagger expert --task {task}{flag} --seeds {seeds}",
        "commit": source_revision() or "unknown",
    }


def expert_table(rows: list[dict[str, Any]], seconds: float | None = None) -> str:
    """A one-row Markdown table: episodes, successes, success rate (95% Wilson interval), mean
    reward, episode length (min / mean / max) and, given the rollouts' wall time ``seconds``,
    environment steps per second."""
    if not rows:
        raise ValueError("expert_table needs at least one row (evaluate at least one seed)")
    s = summarize(rows)
    steps = [int(r["steps"]) for r in rows]
    head = "| episodes | successes | success rate | mean reward | episode steps (min / mean / max) |"
    cells = (
        f"| {s['episodes']} | {s['successes']} | {s['success_rate']:.1%} "
        f"({s['success_ci_low']:.0%}-{s['success_ci_high']:.0%}) "
        f"| {s['mean_reward']:.1f} | {min(steps)} / {s['mean_steps']:.1f} / {max(steps)} |"
    )
    rule = "|---:|---:|---:|---:|---:|"
    if seconds is not None:
        head, rule = head + " steps per second |", rule + "---:|"
        cells += f" {sum(steps) / seconds:.0f} |" if seconds > 0 else " - |"
    return "\n".join([head, rule, cells])
