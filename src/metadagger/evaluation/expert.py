"""Measure a task's expert: drive the learner env with the expert's own labels, one episode a seed.

Driving with ``info["expert_label"]`` (not the expert's full action) measures the expert as the
learner sees it: for CarRacing that is the steering snapped to the 20 classes.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from metadagger.tasks.base import Task


def run_expert_episode(task: Task, seed: int) -> dict[str, Any]:
    """One episode of ``task``'s learner env on ``seed``, every action the expert's label.

    Returns:
        ``{"seed", "success", "reward", "steps"}``.
    """
    env = task.make_env()
    try:
        _, info = env.reset(seed=int(seed))
        reward, steps, done = 0.0, 0, False
        while not done:
            _, r, terminated, truncated, info = env.step(info["expert_label"])
            reward += float(r)
            steps += 1
            done = terminated or truncated
        return {"seed": int(seed), "success": bool(info["is_success"]), "reward": reward, "steps": steps}
    finally:
        env.close()


def evaluate_expert(task: Task, seeds: Iterable[int], *, progress: bool = True) -> list[dict[str, Any]]:
    """Run :func:`run_expert_episode` on every seed, in order.

    Args:
        task: the task whose expert is measured.
        seeds: env seeds, one episode each.
        progress: show a tqdm progress bar with the running success count.

    Returns:
        One row per seed: ``seed``, ``success``, ``reward``, ``steps``.
    """
    rows: list[dict[str, Any]] = []
    bar = tqdm(list(seeds), desc=f"expert {task.name}", unit="ep", disable=not progress)
    for seed in bar:
        rows.append(run_expert_episode(task, seed))
        bar.set_postfix(success=f"{sum(r['success'] for r in rows)}/{len(rows)}")
    return rows


def expert_table(rows: list[dict[str, Any]]) -> str:
    """A one-row Markdown table: episodes, successes, success rate, mean reward, mean steps."""
    if not rows:
        raise ValueError("expert_table needs at least one row (evaluate at least one seed)")
    successes = sum(bool(r["success"]) for r in rows)
    return "\n".join(
        [
            "| episodes | successes | success rate | mean reward | mean steps |",
            "|---:|---:|---:|---:|---:|",
            f"| {len(rows)} | {successes} | {successes / len(rows):.1%} | "
            f"{np.mean([r['reward'] for r in rows]):.1f} | {np.mean([r['steps'] for r in rows]):.1f} |",
        ]
    )
