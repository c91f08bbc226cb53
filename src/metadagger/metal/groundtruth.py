"""The ground-truth policy pi* (paper 3.4.1): one BC fit on expert demos of K seeds, then DAgger
rounds over all K seeds. Its layers 1..n-1 are frozen into every per-seed policy afterwards.

Artifacts under ``<run>/groundtruth/``: ``policy.safetensors`` (pi*), ``metrics.json`` (success on
its own seeds and on unseen seeds) and ``rounds/round_<k>.safetensors`` checkpoints, so a killed
run resumes after its last finished fit.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

from metadagger.errors import UserError
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.imitation.bc import BCConfig, fit_or_resume
from metadagger.imitation.dagger import DAggerConfig, run_dagger
from metadagger.imitation.data import Dataset
from metadagger.imitation.rollouts import collect
from metadagger.io import write_json
from metadagger.policies import Policy, load_policy, make_policy
from metadagger.tasks.base import Task


@dataclass(frozen=True)
class GroundTruthConfig:
    """How pi* is trained and measured."""

    seeds: tuple[int, ...] = tuple(range(0, 20))
    """The K seeds whose demos and DAgger rollouts train pi*."""
    eval_seeds: tuple[int, ...] = tuple(range(900, 920))
    """Unseen seeds pi* is measured on (never used for pairs or evaluation)."""
    dagger_rounds: int = 5
    """DAgger rounds after the BC fit (the paper uses 5)."""
    bc: BCConfig = field(default_factory=lambda: BCConfig(lr=1e-3, batch_size=64, epochs=3))
    """The whole-policy fit done on the demos and again after every round."""
    seed: int = 0
    """Seed of pi*'s initial weights."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("groundtruth.seeds must not be empty")
        if set(self.seeds) & set(self.eval_seeds):
            raise UserError("groundtruth.eval_seeds must be unseen: they overlap groundtruth.seeds; pick disjoint ranges")
        if self.dagger_rounds < 0:
            raise UserError(f"groundtruth.dagger_rounds must be >= 0, got {self.dagger_rounds}")
        if self.bc.head_only:
            raise UserError("groundtruth.bc.head_only must be false: pi* trains the whole policy")


def groundtruth_path(run: str | Path) -> Path:
    """Where pi* of a run lives."""
    return Path(run) / "groundtruth" / "policy.safetensors"


def load_groundtruth(run: str | Path) -> Policy:
    """pi* of a run; a missing or corrupt file is a :class:`UserError` naming it."""
    path = groundtruth_path(run)
    if not path.is_file():
        raise UserError(f"pi* not found at {path}; run `metadagger groundtruth --out {run}` first")
    return load_policy(path)


def train_groundtruth(task: Task, config: GroundTruthConfig, run: str | Path, *, progress: bool = True) -> dict:
    """Train pi* (or reuse a finished one) and return its metrics."""
    folder = Path(run) / "groundtruth"
    if groundtruth_path(run).is_file() and (folder / "metrics.json").is_file():
        return json.loads((folder / "metrics.json").read_text())
    rounds_dir = folder / "rounds"

    demos = collect(task, config.seeds, policy=None, progress=progress)
    data = Dataset.concat(*(t.to_dataset() for t in demos))
    policy = make_policy(task, seed=config.seed)
    fit_or_resume(policy, data, config.bc, rounds_dir / "round_0.safetensors", progress=progress)
    history = []
    if config.dagger_rounds:
        result = run_dagger(
            policy, task, config.seeds, initial=data,
            config=DAggerConfig(rounds=config.dagger_rounds, bc=config.bc),
            progress=progress, checkpoints=rounds_dir,
        )
        history = result.rounds
    own = summarize(evaluate_policy(task, policy, config.seeds, label="pi* on its seeds", progress=progress))
    unseen = summarize(evaluate_policy(task, policy, config.eval_seeds, label="pi* on unseen seeds", progress=progress))
    metrics = {"own_seeds": own, "unseen_seeds": unseen, "rounds": history, "expert_queries": history[-1]["dagger/expert_queries"] if history else len(data)}
    policy.save(groundtruth_path(run))
    write_json(folder / "metrics.json", metrics)
    return metrics


@functools.lru_cache(maxsize=2)
def cached_groundtruth(path: str) -> Policy:
    """pi* loaded once per worker process (callers copy it before changing it)."""
    return load_policy(path)


def head_from_groundtruth(groundtruth: Policy, seed: int) -> Policy:
    """A copy of pi* with its trunk frozen and its head re-initialised from ``seed``."""
    policy = groundtruth.copy()
    policy.freeze_trunk()
    policy.reset_head(seed)
    return policy
