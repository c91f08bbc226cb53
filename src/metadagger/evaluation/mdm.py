"""Direct mapping (MDM) and one-shot evaluation on unseen seeds (paper 4.1, Tables 1-5).

Per seed: the seed's expert demonstration -> a head fitted by BC on pi*'s frozen trunk (exactly as
for the pairs) -> each method's head (the BC head itself, each mapper's output, the controls) ->
one rollout each. One-shot: for each mapper whose head failed, its output initialises the head,
which is refitted once on the same demonstration and rolled out again. A mapper that reads the
seed's context gets it from the demonstration and one rollout of the BC head
(:mod:`metadagger.metal.context`); its rows give that rollout's env steps as ``unlabelled_steps``. Every evaluated head is
saved (``eval/heads/<method>/<seed>.safetensors``, tensor ``head``) so any row can be replayed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.evaluation.rows import ROW_FIELDS, write_csv
from metadagger.imitation.bc import BCConfig, FeatureCache, fit_bc
from metadagger.imitation.rollouts import Trajectory, rollout
from metadagger.utils.io import save_tensors
from metadagger.runfolder.layout import RunLayout
from metadagger.mapping.mappers import cached_mapper
from metadagger.mapping.registry import context_inputs, kind_names
from metadagger.metal.context import bc_rollout, seed_context
from metadagger.metal.groundtruth import cached_groundtruth, head_from_groundtruth
from metadagger.runfolder.driver import RowLog, SeedJob, Stamp, StageOptions, drive, plan
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task

#: Prefix of the one-shot rows of a mapper kind: ``oneshot-<kind>``.
ONESHOT_PREFIX = "oneshot-"


@dataclass(frozen=True)
class EvalConfig:
    """Which unseen seeds and methods are evaluated."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or pairs); the paper uses 20."""
    methods: tuple[str, ...] = ("dm", "sam", "tam", "ridge", "mean-da", "pistar-head")
    """Mapper kinds evaluated beside BC (:mod:`metadagger.mapping.registry`): the paper's dm, sam,
    tam, the ridge baseline and the controls mean-da and pistar-head."""
    oneshot: bool = True
    """Also run one-shot learning for every mapper that fails on a seed (Tables 3-5)."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("evaluate.seeds must not be empty")
        unknown = sorted(set(self.methods) - set(kind_names()))
        if unknown:
            raise UserError(f"evaluate.methods has unknown method(s) {unknown}; allowed: {', '.join(kind_names())}")
        if len(set(self.methods)) != len(self.methods):
            raise UserError(f"evaluate.methods lists a method twice: {list(self.methods)}; list each once")


@dataclass(frozen=True)
class EvalJob(SeedJob):
    """One seed's MDM evaluation; its methods are ``bc`` and/or mapper kinds."""

    mappers: dict[str, str]
    """Mapper file of every kind this job evaluates."""
    bc: BCConfig
    oneshot: bool
    early_stop: float | None = None
    """The pairs' early-stop threshold: it cuts the BC rollout of a context, as in the pairs."""


def evaluate_seed(job: EvalJob) -> dict[str, Any]:
    """Evaluate BC and the job's mappers (and their one-shot refits) on one seed; returns
    ``seed``, ``entries`` (``{method: rows}``) and ``heads`` (``{row method: head}``)."""
    policy = head_from_groundtruth(cached_groundtruth(job.groundtruth), job.bc.head_init_seed(job.seed))
    bc_config = dataclasses.replace(job.bc, seed=job.seed)
    env = job.task.make_env()
    entries: dict[str, list[dict[str, Any]]] = {}
    heads: dict[str, np.ndarray] = {}

    def run(owner: str, method: str, head: np.ndarray, queries: int, extra: dict[str, int]) -> Trajectory:
        policy.load_head_vector(torch.from_numpy(head))
        traj = rollout(env, seed=job.seed, policy=policy)
        heads[method] = head
        entries.setdefault(owner, []).append({"method": method, "seed": job.seed, "success": bool(traj.success),
                                              "reward": float(traj.reward), "steps": int(traj.steps), "expert_queries": queries,
                                              **extra})
        return traj

    try:
        demo = rollout(env, seed=job.seed, policy=None).to_dataset()
        cache = FeatureCache(policy)
        fit_bc(policy, demo, bc_config, cache=cache)
        w_bc = policy.head_vector().numpy().copy()
        kinds = [m for m in job.methods if m != "bc"]
        bc_traj = run("bc", "bc", w_bc, len(demo), {}) if "bc" in job.methods else None
        context, unlabelled = None, {}
        if any(cached_mapper(job.mappers[kind]).needs_context for kind in kinds):
            # without an early stop the BC row's rollout is the context's (rollouts are deterministic)
            reuse = bc_traj is not None and job.early_stop is None
            unlabelled_rollout = bc_traj if reuse else bc_rollout(env, policy, job.seed, job.early_stop)  # labels never used
            context, unlabelled = seed_context(cache, demo.obs, unlabelled_rollout.obs), {"unlabelled_steps": unlabelled_rollout.steps}
        for kind in kinds:
            mapper = cached_mapper(job.mappers[kind])
            extra = unlabelled if mapper.needs_context else {}
            mapped = mapper(w_bc, context)
            if run(kind, kind, mapped, len(demo), extra).success or not job.oneshot:
                continue
            policy.load_head_vector(torch.from_numpy(mapped))
            fit_bc(policy, demo, bc_config, cache=cache)
            # one-shot reuses the same demonstration: no further expert queries
            run(kind, ONESHOT_PREFIX + kind, policy.head_vector().numpy().copy(), len(demo), extra)
    finally:
        env.close()
    return {"seed": job.seed, "entries": entries, "heads": heads}


def mdm_stamps(task: Task, layout: RunLayout, config: EvalConfig, bc: BCConfig, early_stop: float | None = None) -> dict[str, Stamp]:
    """What each MDM method's rows are made from: the protocol's settings, pi* and its mapper (and,
    for a mapper with a context, the early stop of its BC rollout)."""
    common = {"protocol": "mdm", "task": task.name, "bc": stamp_of(bc), "oneshot": config.oneshot,
              "groundtruth_fingerprint": file_fingerprint(layout.groundtruth)}
    return {"bc": common, **{kind: {**common, "mapper_fingerprint": file_fingerprint(layout.mapper(kind)),
                                    **context_inputs(kind, early_stop)}
                             for kind in config.methods}}


def evaluate_run(
    task: Task,
    layout: RunLayout,
    config: EvalConfig,
    *,
    bc: BCConfig,
    early_stop: float | None = None,
    options: StageOptions = StageOptions(),
) -> list[dict[str, Any]]:
    """Evaluate the missing (seed, method) rows of ``config``; write ``eval/mdm.csv`` (BC +
    mappers) and, when ``config.oneshot``, ``eval/oneshot.csv``; return the rows of ``config``.
    ``early_stop``: the pairs' threshold, which cuts the BC rollout of a mapper's context.

    Rows made from another pi*, mapper or settings are redone with ``options.rebuild``, else an error.
    """
    missing = [m for m in config.methods if not layout.mapper(m).is_file()]
    if missing:
        raise UserError(f"mappers not trained yet: {', '.join(missing)}; run `metadagger train-mapper --out {layout.root} --kind all` first")
    stamps = mdm_stamps(task, layout, config, bc, early_stop)
    log = RowLog(layout.eval_log("mdm"))
    todo = plan(config.seeds, stamps, log, rebuild=options.rebuild, what="MDM evaluation",
                fix=f"run `metadagger evaluate --out {layout.root} --rebuild` to redo it, or `metadagger reproduce`")
    mappers = {m: str(layout.mapper(m)) for m in config.methods}
    jobs = [EvalJob(task=task, groundtruth=str(layout.groundtruth), mappers=mappers, seed=p.seed, methods=p.methods,
                    bc=bc, oneshot=config.oneshot, early_stop=early_stop) for p in todo]

    def save(result: dict[str, Any]) -> None:
        for method, head in result["heads"].items():
            head = torch.from_numpy(np.array(head))  # a copy: arrays from Ray workers are read-only
            save_tensors(layout.heads(method) / f"{result['seed']}.safetensors", {"head": head})

    drive(evaluate_seed, jobs, log=log, stamps=stamps, save=save, options=options, desc="evaluate")
    rows = log.rows(config.seeds, stamps)
    # the column appears only where a mapper read a context, so other runs' tables keep their form
    fields = ROW_FIELDS + (("unlabelled_steps",) if any("unlabelled_steps" in r for r in rows) else ())
    write_csv(layout.eval_table("mdm"), [r for r in rows if not r["method"].startswith(ONESHOT_PREFIX)], fields)
    if config.oneshot:
        write_csv(layout.eval_table("oneshot"), [r for r in rows if r["method"].startswith(ONESHOT_PREFIX)], fields)
    return rows
