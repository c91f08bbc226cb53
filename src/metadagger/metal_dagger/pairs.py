"""Per-seed (w_BC, w_DA) pairs (paper 3.4.2).

For each seed, the steps of :mod:`metadagger.metal_dagger.method`: the demonstration, w_BC (a fresh head
on pi*'s frozen trunk fitted by BC on it), then DAgger rounds from there -> w_DA; both rolled out.
The seed's context is stored with its pair. The seeds run in parallel through
:mod:`metadagger.utils.executors`; the driver alone writes each pair to the
:class:`~metadagger.metal_dagger.store.PairStore` as soon as it arrives, so a
killed run resumes with the seeds that are not stored yet.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.data import Aggregate
from metadagger.imitation.early_stop import check_threshold
from metadagger.imitation.lanes import check_lanes, lanes_stamp
from metadagger.imitation.rollouts import Trajectory
from metadagger.metal_dagger.lane_blocks import in_blocks
from metadagger.metal_dagger.method import (
    CONTEXT_PARTS,
    SeedLearner,
    bc_head,
    dagger_rounds,
    demonstration,
    seed_context,
    seeded,
)
from metadagger.metal_dagger.pistar import load_pistar
from metadagger.metal_dagger.store import PairStore
from metadagger.runfolder.driver import SeedJob, StageOptions, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import describe_changes, file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import write_json
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT

KEEP_RULES = ("bc_fail_da_success", "da_success", "all")


#: A pair's four outcomes: BC succeeded or failed on the seed, and DAgger did.
OUTCOMES = ("bc_ok/da_ok", "bc_ok/da_fail", "bc_fail/da_ok", "bc_fail/da_fail")

#: The median relative head change (||w_DA - w_BC|| / ||w_BC||) below which reproduce warns that
#: DAgger barely moved the heads: a third of what the weak 2-epoch fits moved them on CarRacing's
#: pair seeds (31%, where working fits moved them 101%; docs/custom_task.md).
NEGLIGIBLE_HEAD_CHANGE = 0.1


@dataclass(frozen=True)
class PairConfig:
    """How each seed's pair is made and which pairs are kept."""

    seeds: tuple[int, ...] = tuple(range(1000, 1100))
    """Seeds to collect pairs on (disjoint from pi*'s and the evaluation seeds)."""
    dagger_rounds: int = 3
    """DAgger rounds on the seed after the BC fit (the paper uses 3)."""
    bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=12, head_only=True))
    """The head-only BC fit on the seed's demonstration (its ``seed`` is replaced by the env seed).
    The default (lr 1e-4, batch 10, 12 epochs, as CarRacing's presets) moves a head: on CarRacing
    pair seeds 1000-1007 DAgger moved it by a median 101% of its norm and succeeded on 6 of 8,
    where 2 epochs moved it 31% and succeeded on none (docs/custom_task.md)."""
    dagger_bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=12, head_only=True))
    """The head-only refit of every DAgger round (the same default as ``bc``)."""
    keep: str = "bc_fail_da_success"
    """Which pairs train the mappers: ``bc_fail_da_success`` (the paper's filter), ``da_success`` or ``all``."""
    val_fraction: float = 0.2
    """Share of the kept pairs held out for validation (75 of 375 in the paper)."""
    early_stop: float | None = None
    """Cosine early-stop threshold of the learner's rollouts (paper 3.4.2, Fetch); None: off."""
    lanes: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """Pair seeds made together, in blocks of this many, their episodes stepped in lockstep at this
    batch shape (:func:`~metadagger.metal_dagger.lane_blocks.in_blocks`); 1 makes each seed alone. The pairs
    depend on it (a batch of one rounds the trunk's last bits otherwise), never on the workers."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("pairs.seeds must not be empty")
        if self.dagger_rounds < 1:
            raise UserError(f"pairs.dagger_rounds must be >= 1, got {self.dagger_rounds}")
        if not (self.bc.head_only and self.dagger_bc.head_only):
            raise UserError("pairs.bc.head_only and pairs.dagger_bc.head_only must be true: only layer n is mapped")
        if self.keep not in KEEP_RULES:
            raise UserError(f"pairs.keep must be one of {', '.join(KEEP_RULES)}, got {self.keep!r}")
        if not 0.0 < self.val_fraction < 1.0:
            raise UserError(f"pairs.val_fraction must be in (0, 1), got {self.val_fraction}")
        check_threshold("pairs.early_stop", self.early_stop)
        check_lanes("pairs.lanes", self.lanes)


@dataclass(frozen=True)
class PairJob(SeedJob):
    """One seed's pair (its one method is ``pair``)."""

    config: PairConfig


def is_kept(rule: str, bc_success: bool, da_success: bool) -> bool:
    """Whether a pair with these outcomes is kept under ``rule``."""
    if rule == "bc_fail_da_success":
        return (not bc_success) and da_success
    if rule == "da_success":
        return da_success
    return True


@dataclass(frozen=True)
class PairRun:
    """One run of a seed's pair procedure."""

    w_bc: np.ndarray
    """The head after BC on the demonstration."""
    w_da: np.ndarray
    """The head after the DAgger rounds."""
    context: np.ndarray
    """The seed's context (:func:`metadagger.metal_dagger.method.seed_context`): what the ``conditioned`` mapper kind
    reads beside w_BC."""
    record: dict[str, Any]
    """``bc`` and ``da`` outcomes, ``kept`` and ``outcome`` (as stored with the pair); for a task
    family also the seed's ``variation``."""
    dagger_features: torch.Tensor | None
    """With ``with_states``: trunk features of the states the learner visited in the DAgger
    rounds, in visiting order."""


def run_pair(
    task: Task,
    pistar: str,
    seed: int,
    config: PairConfig,
    *,
    fit_seed: int | None = None,
    with_states: bool = False,
    on_episode: Callable[[int, Trajectory], None] | None = None,
) -> PairRun:
    """The pair procedure on ``seed``: BC on its demonstration, then DAgger, both rolled out.

    ``fit_seed`` seeds the fits' shuffling (default: ``seed``, as the pairs do); another value
    gives the same procedure with other fits, on the same demonstration, expert and env seeds.
    ``with_states`` also returns the DAgger states' trunk features (the diagnostics need them;
    collecting pairs does not). ``on_episode(round, trajectory)`` receives every episode the pair
    is fit on: the demonstration (round 0), then each DAgger round's rollout.
    """
    fit_seed = seed if fit_seed is None else fit_seed
    with SeedLearner(task, pistar, seed, head_init_seed=config.bc.head_init_seed(seed)) as learner:
        fresh = learner.head()
        demo = demonstration(learner)
        data = demo.to_dataset()
        w_bc = bc_head(learner, data, seeded(config.bc, fit_seed))
        # BC's own rollout, under the pairs' early stop, is the one DAgger's first round labels
        first = learner.roll(w_bc, early_stop=config.early_stop)
        rounds = list(
            dagger_rounds(
                learner,
                start=w_bc,
                first_rollout=first,
                demo=demo,
                rounds=config.dagger_rounds,
                fit=seeded(config.dagger_bc, fit_seed),
                early_stop=config.early_stop,
                origin=fresh,
            )
        )
        context = seed_context(learner.cache, data, first.to_dataset())
        states = learner.cache.features_of(Aggregate([r.labelled for r in rounds])) if with_states else None
    if on_episode is not None:
        for index, episode in enumerate([demo, first, *(r.rollout for r in rounds[:-1])]):
            on_episode(index, episode)
    final = rounds[-1]
    bc = {
        "success": bool(first.success),
        "reward": float(first.reward),
        "steps": int(first.steps),
        "expert_queries": len(data),
    }
    da = {
        "success": bool(final.rollout.success),
        "reward": float(final.rollout.reward),
        "steps": int(final.rollout.steps),
        "expert_queries": final.queries,
    }
    record = {
        "bc": bc,
        "da": da,
        "kept": is_kept(config.keep, bc["success"], da["success"]),
        "outcome": f"bc_{'ok' if bc['success'] else 'fail'}/da_{'ok' if da['success'] else 'fail'}",
    }
    if demo.variation is not None:
        record["variation"] = demo.variation
    return PairRun(w_bc=w_bc, w_da=final.head, context=context, record=record, dagger_features=states)


def collect_pair(job: PairJob) -> dict[str, Any]:
    """Make one seed's pair; returns ``seed``, ``w_bc``, ``w_da``, ``context`` (float32 arrays) and ``record``."""
    pair = run_pair(job.task, job.pistar, job.seed, job.config)
    return {"seed": job.seed, "w_bc": pair.w_bc, "w_da": pair.w_da, "context": pair.context, "record": pair.record}


def pair_stamp(task: Task, layout: RunLayout, config: PairConfig) -> dict[str, Any]:
    """What a pair is made from: the task, the pair settings (not the seed list) and pi*."""
    return {
        **kernel_stamp(),
        **task_stamp(task),
        **stamp_of(config, drop=("seeds", "val_fraction")),
        **lanes_stamp(config.lanes),
        "context": list(CONTEXT_PARTS),
        "pistar_fingerprint": file_fingerprint(layout.pistar),
    }


def pair_status(task: Task, layout: RunLayout, config: PairConfig) -> tuple[list[int], list[str]]:
    """The seeds of ``config`` without a current pair, and what changed for the stale ones
    (empty lists: every pair is there and made from today's pi* and settings)."""
    stamp = pair_stamp(task, layout, config)
    logged = PairStore(layout.pairs_dir).stamps()
    missing = [s for s in config.seeds if logged.get(s, {}).get("pair") != stamp]
    stale = next((logged[s]["pair"] for s in missing if s in logged), None)
    return missing, describe_changes(stale, stamp) if stale is not None else []


def collect_pairs(
    task: Task,
    layout: RunLayout,
    config: PairConfig,
    options: StageOptions = StageOptions(),
) -> dict[str, Any]:
    """Collect the pairs of every seed not stored yet (and, with ``options.rebuild``, of every seed whose
    pair was made from another pi* or other settings), then write and return the outcome summary."""
    load_pistar(layout)  # a missing or corrupt pi* is named before any work
    store = PairStore(layout.pairs_dir)
    stamps = {"pair": pair_stamp(task, layout, config)}
    todo = plan(
        config.seeds,
        stamps,
        store,
        rebuild=options.rebuild,
        called="the pair",
        fix=f"run `metadagger pairs --out {layout.root} --rebuild` to collect them again, or `metadagger reproduce`",
    )
    jobs = [PairJob(task=task, pistar=str(layout.pistar), seed=p.seed, methods=p.methods, config=config) for p in todo]
    work, units = in_blocks(collect_pair, jobs, config.lanes, options.workers)
    drive(work, units, log=store, stamps=stamps, options=options, desc="pairs")
    current = {s for s, stamp in store.stamps().items() if stamp["pair"] == stamps["pair"]} & set(config.seeds)
    summary = summarize_pairs([r for r in store.records() if r["seed"] in current] if current else [])
    if current:
        summary["head_change"] = head_change(store, sorted(current))
    write_json(layout.pairs_summary, summary)
    return summary


def head_change(store: PairStore, seeds: list[int]) -> dict[str, float]:
    """How far DAgger moved each seed's head: ``||w_DA - w_BC|| / ||w_BC||`` over ``seeds``'
    pairs (its ``median``, ``min`` and ``max``)."""
    w_bc, w_da = store.load(seeds)
    change = (w_da - w_bc).norm(dim=1) / w_bc.norm(dim=1).clamp_min(1e-12)
    return {"median": float(change.median()), "min": float(change.min()), "max": float(change.max())}


def negligible_change_warning(summary: dict[str, Any]) -> str | None:
    """One line when DAgger barely moved the heads (median relative change below
    :data:`NEGLIGIBLE_HEAD_CHANGE`): a mapper then has nothing to learn; ``None`` otherwise."""
    change = summary.get("head_change")
    if change is None or change["median"] >= NEGLIGIBLE_HEAD_CHANGE:
        return None
    return (
        f"warning: DAgger moved the heads by a median {change['median']:.1%} of their norm (||w_DA - w_BC|| / "
        "||w_BC||, "
        f"{change['min']:.1%}-{change['max']:.1%}), below {NEGLIGIBLE_HEAD_CHANGE:.0%}: mapped and BC heads will act "
        "alike; "
        "give pairs.bc and pairs.dagger_bc more epochs or a larger lr (docs/custom_task.md)"
    )


def summarize_pairs(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts and shares of the four outcomes (BC ok/fail x DAgger ok/fail) and of kept pairs."""
    n = len(records)
    outcomes = Counter(r["outcome"] for r in records)
    return {
        "seeds": n,
        "kept": sum(bool(r["kept"]) for r in records),
        "outcomes": {k: outcomes.get(k, 0) for k in OUTCOMES},
        "shares": {k: (outcomes.get(k, 0) / n if n else 0.0) for k in OUTCOMES},
        "mean_reward": {
            "bc": float(np.mean([r["bc"]["reward"] for r in records])) if n else 0.0,
            "da": float(np.mean([r["da"]["reward"] for r in records])) if n else 0.0,
        },
    }
