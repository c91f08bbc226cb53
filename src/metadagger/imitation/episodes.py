"""Roll a policy (or the expert) out on evaluation seeds and return one row per episode."""

from __future__ import annotations

from typing import Sequence


from metadagger.imitation.rollouts import rollout
from metadagger.policies import Policy
from metadagger.progress import progress_bar
from metadagger.tasks.base import Task


def evaluate_policy(
    task: Task,
    policy: Policy | None,
    seeds: Sequence[int],
    *,
    label: str = "eval",
    progress: bool = True,
) -> list[dict]:
    """One row per seed (seed, success, reward, steps); ``policy=None`` lets the expert act."""
    env = task.make_env()
    rows = []
    try:
        for seed in progress_bar(seeds, desc=label, enabled=progress, leave=False):
            traj = rollout(env, seed=seed, policy=policy)
            rows.append({"seed": int(seed), "success": bool(traj.success), "reward": float(traj.reward), "steps": int(traj.steps)})
    finally:
        env.close()
    return rows
