"""DAgger of a whole policy over many seeds, composed from behavioural cloning: roll out on every
seed, let the expert label every visited state, aggregate, refit the whole network.

This is the DAgger that trains pi* (:mod:`metadagger.metal_dagger.pistar`) and the plain DAgger of
``metadagger demo``. MetaL DAgger's own DAgger, on one seed with pi*'s trunk frozen and a head
refitted each round, with or without a gate, is
:func:`metadagger.metal_dagger.method.dagger_rounds`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, fit_or_resume
from metadagger.imitation.collect import collect
from metadagger.imitation.data import Aggregate, Dataset
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.rollouts import EarlyStop, Trajectory
from metadagger.policies import Policy
from metadagger.tasks.base import Task
from metadagger.utils.progress import progress_bar


@dataclass(frozen=True)
class DAggerConfig:
    """How a DAgger run proceeds."""

    rounds: int = 3
    """Roll-out/aggregate/refit iterations."""
    bc: BCConfig = field(default_factory=BCConfig)
    """The fit done on the aggregated dataset each round."""
    reset_each_round: bool = False
    """Re-initialise the trained weights (from ``bc.seed``; the head only if the trunk is frozen or
    ``bc.head_only``) before each refit, instead of continuing from the current weights."""

    def __post_init__(self) -> None:
        if not isinstance(self.rounds, int) or self.rounds < 1:
            raise UserError(f"DAggerConfig.rounds must be an integer >= 1, got {self.rounds!r}")
        if not isinstance(self.bc, BCConfig):
            raise UserError(f"DAggerConfig.bc must be a BCConfig, got {type(self.bc).__name__}")


@dataclass(frozen=True)
class DAggerResult:
    """What a DAgger run produced.

    Attributes:
        rounds: one metrics dict per round (see :func:`run_whole_policy_dagger`).
        dataset: the final aggregated dataset (initial data first, then each round's rollouts,
            one part per rollout).
    """

    rounds: list[dict[str, Any]]
    dataset: Aggregate


def run_whole_policy_dagger(
    policy: Policy,
    task: Task,
    seeds: Iterable[int],
    *,
    initial: Dataset | Aggregate,
    config: DAggerConfig,
    progress: bool = False,
    on_round: Callable[[int, Policy, dict[str, Any]], None] | None = None,
    early_stop_factory: Callable[[], EarlyStop] | None = None,
    cache: FeatureCache | None = None,
    checkpoints: str | Path | None = None,
    on_rollouts: Callable[[int, list[Trajectory]], None] | None = None,
    workers: int = 1,
    lanes: int = 1,
) -> DAggerResult:
    """Improve ``policy`` in place with DAgger on ``task``.

    Each round rolls out the current policy once per seed, keeps every visited state with the
    expert's label, appends them to the aggregated dataset and refits the policy on all of it.
    The caller usually fits ``policy`` on ``initial`` first (the BC policy); its expert queries
    are counted as ``len(initial)``.

    Args:
        policy: the learner, trained in place.
        task: the task whose learner env is rolled out.
        seeds: env seeds rolled out every round.
        initial: the demonstrations the aggregate starts from.
        config: rounds and the per-round fit.
        progress: show progress bars.
        on_round: called as ``on_round(round_idx, policy, metrics)`` after each refit.
        early_stop_factory: builds the :class:`EarlyStop` used in the rollouts.
        cache: trunk features shared with earlier head-only fits (e.g. the BC fit on ``initial``);
            a fresh one, used by every round, if None.
        checkpoints: folder for ``round_<k>.safetensors`` (the policy after round k's refit). A
            round whose checkpoint exists loads it instead of refitting, so a killed run resumes:
            its rollouts are re-done (deterministic) to rebuild the aggregated dataset, the
            expensive fits are not. ``final_loss`` and ``epoch_losses`` are None for a resumed round.
        on_rollouts: called as ``on_rollouts(round_idx, trajectories)`` with each round's rollouts
            before its refit (e.g. to export the episodes).
        workers: roll the seeds out in a process pool of this size (see :func:`collect`).
        lanes: step this many of a round's episodes in lockstep (see :func:`collect`).

    Returns:
        Per-round metrics, keys namespaced ``dagger/``: ``round`` (1-based), ``success_rate``,
        ``mean_reward`` and ``mean_steps`` of that round's rollouts (so of the policy *before*
        the round's refit: round 1 measures the initial policy), ``expert_queries`` (cumulative,
        including ``initial``), ``dataset_size``, and ``final_loss`` and ``epoch_losses`` (the
        mean training loss of every epoch) of the refit; and the aggregated dataset.
    """
    seeds = list(seeds)
    if not seeds:
        raise ValueError("run_whole_policy_dagger needs at least one seed")
    if cache is None and config.bc.head_only:
        cache = FeatureCache(policy)
    dataset = Aggregate([initial])
    queries = len(initial)
    history: list[dict[str, Any]] = []
    for round_idx in progress_bar(range(1, config.rounds + 1), desc="dagger", enabled=progress, leave=False):
        trajectories = collect(
            task,
            seeds,
            policy=policy,
            progress=progress,
            early_stop_factory=early_stop_factory,
            workers=workers,
            lanes=lanes,
        )
        if on_rollouts is not None:
            on_rollouts(round_idx, trajectories)
        dataset = dataset.append(*(t.to_dataset() for t in trajectories))
        queries += sum(t.expert_queries for t in trajectories)
        if config.reset_each_round and not _has_checkpoint(checkpoints, round_idx):
            # a frozen trunk (e.g. pi*'s layers 1..n-1) is never re-initialised
            trunk_frozen = not any(p.requires_grad for p in policy.net.trunk.parameters())
            policy.net.init_weights(config.bc.seed, head_only=config.bc.head_only or trunk_frozen)
        losses = fit_or_resume(
            policy,
            dataset,
            config.bc,
            _checkpoint(checkpoints, round_idx),
            cache=cache,
            called=f"DAgger round {round_idx}'s fit",
        )
        metrics = {
            "dagger/round": round_idx,
            "dagger/success_rate": float(np.mean([t.success for t in trajectories])),
            "dagger/mean_reward": float(np.mean([t.reward for t in trajectories])),
            "dagger/mean_steps": float(np.mean([t.steps for t in trajectories])),
            "dagger/expert_queries": queries,
            "dagger/dataset_size": len(dataset),
            "dagger/final_loss": None if losses is None else losses[-1],
            "dagger/epoch_losses": losses,
        }
        history.append(metrics)
        if on_round is not None:
            on_round(round_idx, policy, metrics)
    return DAggerResult(rounds=history, dataset=dataset)


def _checkpoint(folder: str | Path | None, round_idx: int) -> Path | None:
    return None if folder is None else Path(folder) / f"round_{round_idx}.safetensors"


def _has_checkpoint(folder: str | Path | None, round_idx: int) -> bool:
    path = _checkpoint(folder, round_idx)
    return path is not None and path.is_file()
