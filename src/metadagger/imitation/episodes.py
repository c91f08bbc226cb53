"""Roll a policy (or the expert) out on evaluation seeds and return one row per episode."""

from __future__ import annotations

from typing import Sequence

from metadagger.imitation.collect import collect
from metadagger.imitation.rollouts import Trajectory
from metadagger.policies import Policy
from metadagger.tasks.base import Task


def evaluate_policy(
    task: Task,
    policy: Policy | None,
    seeds: Sequence[int],
    *,
    label: str = "eval",
    progress: bool = True,
    workers: int = 1,
    lanes: int = 1,
) -> list[dict]:
    """One row per seed (seed, success, reward, steps); ``policy=None`` lets the expert act.
    ``workers`` > 1 rolls chunks of seeds out in a process pool (the same rows); ``lanes`` > 1
    steps that many episodes in lockstep (:func:`~metadagger.imitation.collect.collect`)."""
    return collect(
        task, seeds, policy=policy, progress=progress, workers=workers, each=episode_row, desc=label, lanes=lanes
    )


def episode_row(trajectory: Trajectory) -> dict:
    """An episode's evaluation row: seed, success, reward, steps."""
    return {
        "seed": trajectory.seed,
        "success": bool(trajectory.success),
        "reward": float(trajectory.reward),
        "steps": int(trajectory.steps),
    }
