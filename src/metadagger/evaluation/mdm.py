"""Direct mapping (MDM) and one-shot evaluation on unseen seeds (paper 4.1, Tables 1-5).

Per seed, the steps of :mod:`metadagger.metal_dagger.method`: the seed's expert demonstration -> w_BC
(exactly as for the pairs) -> each method's head (the BC head itself, each mapper's output, the
controls) -> one rollout each. One-shot: for each mapper whose head failed, its output initialises
the head, which is refitted once on the same demonstration and rolled out again. A mapper that
reads the seed's context gets it from the demonstration and one rollout of the BC head; its rows
give that rollout's env steps as ``unlabelled_steps``. Every evaluated head is
saved (``eval/heads/<method>/<seed>.safetensors``, tensor ``head``) so any row can be replayed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.evaluation.rows import ROW_FIELDS, write_csv
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.lanes import check_lanes, lanes_stamp
from metadagger.imitation.rollouts import Trajectory
from metadagger.mapping.mappers import MapperFile, cached_mapper
from metadagger.mapping.registry import context_inputs, kind_names
from metadagger.metal_dagger.lane_blocks import in_blocks
from metadagger.metal_dagger.method import SeedLearner, bc_head, demonstration, map_head, one_shot, seed_context, seeded
from metadagger.runfolder.driver import RowLog, SeedJob, StageOptions, Stamp, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import save_tensors
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT

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
    lanes: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """Seeds evaluated together, in blocks of this many stepped in lockstep lanes, one trunk
    forward per step at this batch shape (:mod:`metadagger.imitation.lanes`); 1 evaluates each
    seed alone. The rows depend on it, never on the workers."""

    def __post_init__(self) -> None:
        check_lanes("evaluate.lanes", self.lanes)
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

    mappers: dict[str, MapperFile]
    """Mapper file of every kind this job evaluates."""
    bc: BCConfig
    oneshot: bool
    early_stop: float | None = None
    """The pairs' early-stop threshold: it cuts the BC rollout of a context, as in the pairs."""


def evaluate_seed(job: EvalJob) -> dict[str, Any]:
    """Evaluate BC and the job's mappers (and their one-shot refits) on one seed; returns
    ``seed``, ``entries`` (``{method: rows}``) and ``heads`` (``{row method: head}``)."""
    entries: dict[str, list[dict[str, Any]]] = {}
    heads: dict[str, np.ndarray] = {}
    fit = seeded(job.bc, job.seed)
    with SeedLearner(job.task, job.pistar, job.seed, head_init_seed=job.bc.head_init_seed(job.seed)) as learner:

        def test(owner: str, method: str, head: np.ndarray, extra: dict[str, int]) -> Trajectory:
            trajectory = learner.roll(head)
            heads[method] = head
            entries.setdefault(owner, []).append(
                {
                    "method": method,
                    "seed": job.seed,
                    "success": bool(trajectory.success),
                    "reward": float(trajectory.reward),
                    "steps": int(trajectory.steps),
                    "expert_queries": len(demo),
                    **extra,
                }
            )
            return trajectory

        demo = demonstration(learner).to_dataset()
        w_bc = bc_head(learner, demo, fit)
        kinds = [m for m in job.methods if m != "bc"]
        mappers = {kind: cached_mapper(job.mappers[kind]) for kind in kinds}
        bc_trajectory = test("bc", "bc", w_bc, {}) if "bc" in job.methods else None
        context, unlabelled = None, {}
        if any(mapper.needs_context for mapper in mappers.values()):
            # without an early stop the BC row's rollout is the context's (rollouts are deterministic);
            # the context's rollout is never labelled
            reuse = bc_trajectory is not None and job.early_stop is None
            rolled = bc_trajectory if reuse else learner.roll(w_bc, early_stop=job.early_stop)
            context, unlabelled = (
                seed_context(learner.cache, demo, rolled.to_dataset()),
                {"unlabelled_steps": rolled.steps},
            )
        for kind, mapper in mappers.items():
            extra = unlabelled if mapper.needs_context else {}
            mapped = map_head(mapper, w_bc, context)
            if test(kind, kind, mapped, extra).success or not job.oneshot:
                continue
            # one-shot reuses the same demonstration: no further expert queries
            test(kind, ONESHOT_PREFIX + kind, one_shot(learner, mapped, demo, fit), extra)
    return {"seed": job.seed, "entries": entries, "heads": heads}


def mdm_stamps(
    task: Task, layout: RunLayout, config: EvalConfig, bc: BCConfig, early_stop: float | None = None
) -> dict[str, Stamp]:
    """What each MDM method's rows are made from: the protocol's settings, pi* and its mapper (and,
    for a mapper with a context, the early stop of its BC rollout)."""
    common = {
        "protocol": "mdm",
        **kernel_stamp(),
        **task_stamp(task),
        "bc": stamp_of(bc),
        "oneshot": config.oneshot,
        **lanes_stamp(config.lanes),
        "pistar_fingerprint": file_fingerprint(layout.pistar),
    }
    return {
        "bc": common,
        **{
            kind: {
                **common,
                "mapper_fingerprint": file_fingerprint(layout.mapper(kind)),
                **context_inputs(kind, early_stop),
            }
            for kind in config.methods
        },
    }


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
        raise UserError(
            f"mappers not trained yet: {', '.join(missing)}; run `metadagger train-mapper --out {layout.root} --kind "
            "all` first"
        )
    stamps = mdm_stamps(task, layout, config, bc, early_stop)
    log = RowLog(layout.eval_log("mdm"))
    todo = plan(
        config.seeds,
        stamps,
        log,
        rebuild=options.rebuild,
        called="MDM evaluation",
        fix=f"run `metadagger evaluate --out {layout.root} --rebuild` to redo it, or `metadagger reproduce`",
    )
    mappers = {m: MapperFile(str(layout.mapper(m)), stamps[m]["mapper_fingerprint"]) for m in config.methods}
    jobs = [
        EvalJob(
            task=task,
            pistar=str(layout.pistar),
            mappers=mappers,
            seed=p.seed,
            methods=p.methods,
            bc=bc,
            oneshot=config.oneshot,
            early_stop=early_stop,
        )
        for p in todo
    ]

    def save(result: dict[str, Any]) -> None:
        for method, head in result["heads"].items():
            head = torch.from_numpy(np.array(head))  # a copy: arrays from Ray workers are read-only
            save_tensors(layout.heads(method) / f"{result['seed']}.safetensors", {"head": head})

    work, units = in_blocks(evaluate_seed, jobs, config.lanes, options.workers)
    drive(work, units, log=log, stamps=stamps, save=save, options=options, desc="evaluate")
    rows = log.rows(config.seeds, stamps)
    # the column appears only where a mapper read a context, so other runs' tables keep their form
    fields = ROW_FIELDS + (("unlabelled_steps",) if any("unlabelled_steps" in r for r in rows) else ())
    write_csv(layout.eval_table("mdm"), [r for r in rows if not r["method"].startswith(ONESHOT_PREFIX)], fields)
    if config.oneshot:
        write_csv(layout.eval_table("oneshot"), [r for r in rows if r["method"].startswith(ONESHOT_PREFIX)], fields)
    return rows
