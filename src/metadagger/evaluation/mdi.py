"""MetaL DAgger as an initialiser (MDI) on unseen seeds: DAgger-MDI vs DAgger-BC vs DAgger
(paper 4.2, Table 6 steps 1-9, Table 7, Fig. 5).

Per seed, every method keeps pi*'s frozen trunk:

1. the expert's demonstration; 2. a head re-initialised from the seed and fitted on it by BC
(w_BC, exactly as for the pairs);
3-5. DAgger-MDI: the mapper's output f(w_BC) initialises the head, refitted on the demonstration;
DAgger-BC: w_BC initialises it, refitted likewise; DAgger: a Xavier head fitted on the
demonstration, which is step 2's fit itself (same seed, same data, same settings), so w_BC is
reused rather than fitted twice;
6. roll out (one-shot test); 7. stop if it succeeded;
8. else one DAgger round: the expert labels the states of that rollout, they join the
demonstration, and the head is fitted on the aggregate starting from the method's saved step-4
initialisation (f(w_BC), w_BC, or the Xavier head for DAgger), as Table 6 says
(``dagger_init="saved"``); ``dagger_init="one-shot"`` continues from the step-5 head instead;
9. roll out again (two-shot test).

``controls`` adds DAgger-MDI rows whose initialiser is another mapper kind, typically the
controls ``mean-da`` (the training pairs' mean w_DA) and ``pistar-head`` (pi*'s own head): method
``dagger-mdi-<kind>``. They tell whether DAgger-MDI gains from what the mapper learned about
each seed or only from starting the refit at a good generic head.

With ``early_stop`` set, every learner rollout runs under a
:class:`~metadagger.imitation.early_stop.CosineEarlyStop` (paper 3.4.2): an episode whose
accumulated cosine distance to the expert passes the threshold is cut off and fails. One row per
(method, seed) goes to ``eval/mdi.csv``; each evaluated head is saved as
``eval/heads/mdi-<method>-<shot>/<seed>.safetensors`` (tensor ``head``) so a row can be replayed
with pi* on its seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.evaluation.rows import write_csv
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.early_stop import CosineEarlyStop, check_threshold
from metadagger.imitation.lanes import check_lanes, lanes_stamp
from metadagger.imitation.rollouts import Trajectory
from metadagger.mapping.mappers import MapperFile, cached_mapper, load_mapper
from metadagger.mapping.registry import context_inputs, kind_names
from metadagger.metal_dagger.lane_blocks import in_blocks
from metadagger.metal_dagger.method import (
    SeedLearner,
    bc_head,
    dagger_rounds,
    demonstration,
    map_head,
    one_shot,
    seed_context,
    seeded,
)
from metadagger.metal_dagger.pistar import cached_pistar
from metadagger.runfolder.driver import RowLog, SeedJob, StageOptions, Stamp, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import save_tensors
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT

#: The three methods of Table 6, in table order: DAgger from the mapper's head, from w_BC and from
#: a fresh Xavier head; one name each, in ``eval/mdi.csv`` and in the benchmark alike.
MDI_METHODS = ("dagger-mdi", "dagger-bc-init", "dagger-xavier")
#: Prefix of the control methods: DAgger-MDI initialised by another mapper kind.
CONTROL_PREFIX = "dagger-mdi-"
#: Where the DAgger round's refit (step 8) starts; see :attr:`MDIConfig.dagger_init`.
DAGGER_INITS = ("saved", "one-shot")
#: The two tests of Table 6 (steps 6 and 9).
SHOTS = ("oneshot", "twoshot")
#: Columns of ``eval/mdi.csv``. ``two_shot_success`` counts a seed solved at either test (the
#: paper's "two-shot" column); the ``two_shot_*`` outcomes are empty when one-shot succeeded.
#: ``expert_queries`` = ``demo_steps`` + the DAgger round's labelled states (= ``one_shot_steps``
#: when the round ran). ``cosine_total`` / ``cosine_per_action``: accumulated and mean cosine
#: distance between the learner's and the expert's actions in the final test (empty for tasks
#: with discrete actions).
MDI_FIELDS = (
    "method",
    "seed",
    "one_shot_success",
    "one_shot_reward",
    "one_shot_steps",
    "one_shot_early_stopped",
    "two_shot_run",
    "two_shot_success",
    "two_shot_reward",
    "two_shot_steps",
    "two_shot_early_stopped",
    "demo_steps",
    "expert_queries",
    "cosine_total",
    "cosine_per_action",
)


@dataclass(frozen=True)
class MDIConfig:
    """The MDI protocol on unseen seeds (paper Table 6)."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or the pairs)."""
    bc: BCConfig | None = None
    """The head-only fit on the demonstration (steps 2 and 5). None (the default): the run's
    ``pairs.bc``, the fit whose w_BC the mapper learned from; a run config rejects any other
    value. Its ``seed`` is replaced by the env seed."""
    dagger_bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=12, head_only=True))
    """The head-only refit of the DAgger round (step 8); the default is ``pairs.dagger_bc``'s."""
    early_stop: float | None = None
    """Threshold of the cosine early stop on every learner rollout (the Fetch presets: 40, docs/fetch.md);
    None: no early stop."""
    mapper: str = "dm"
    """Kind of the mapper that initialises DAgger-MDI (the run's ``mappers/<kind>/``; the paper's
    Table 9 trains one mapping network)."""
    dagger_init: str = "saved"
    """Where step 8's refit starts: ``saved`` (Table 6: the method's step-4 initialisation, a
    fresh Xavier head for DAgger) or ``one-shot`` (the step-5 head that failed the one-shot test)."""
    controls: tuple[str, ...] = ()
    """Further mapper kinds that initialise DAgger-MDI, each in rows of method ``dagger-mdi-<kind>``
    (the Fetch presets: the controls ``mean-da`` and ``pistar-head``, and in the family's also
    ``conditioned``); () for none."""
    lanes: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """Seeds run together, in blocks of this many stepped in lockstep lanes, one trunk forward per
    step at this batch shape (:mod:`metadagger.imitation.lanes`); 1 runs each seed alone. The
    rows depend on it, never on the workers."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("mdi.seeds must not be empty; give e.g. seeds: 5000-5019")
        if not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in self.seeds):
            raise UserError(f"mdi.seeds must be non-negative integers, got {self.seeds!r}")
        if not ((self.bc is None or self.bc.head_only) and self.dagger_bc.head_only):
            raise UserError(
                "mdi.bc.head_only and mdi.dagger_bc.head_only must be true: only layer n is initialised and fitted"
            )
        check_threshold("mdi.early_stop", self.early_stop)
        check_lanes("mdi.lanes", self.lanes)
        if self.mapper not in kind_names():
            raise UserError(f"mdi.mapper must be one of {', '.join(kind_names())}, got {self.mapper!r}")
        if self.dagger_init not in DAGGER_INITS:
            raise UserError(f"mdi.dagger_init must be one of {', '.join(DAGGER_INITS)}, got {self.dagger_init!r}")
        bad = [k for k in self.controls if k not in kind_names() or k == self.mapper]
        if bad or len(set(self.controls)) != len(self.controls):
            raise UserError(
                f"mdi.controls must be distinct mapper kinds of {', '.join(kind_names())} other than mdi.mapper "
                f"({self.mapper!r}), got {list(self.controls)!r}"
            )

    @property
    def kinds(self) -> dict[str, str]:
        """Mapper kind of every DAgger-MDI method: ``dagger-mdi`` and one per control."""
        return {"dagger-mdi": self.mapper, **{CONTROL_PREFIX + kind: kind for kind in self.controls}}

    @property
    def methods(self) -> tuple[str, ...]:
        """Every method evaluated, in row order: :data:`MDI_METHODS`, then the controls."""
        return MDI_METHODS + tuple(CONTROL_PREFIX + kind for kind in self.controls)


@dataclass(frozen=True)
class MDIJob(SeedJob):
    """One seed's MDI evaluation."""

    mappers: dict[str, MapperFile]
    """Mapper file of every DAgger-MDI method of this job (see :attr:`MDIConfig.kinds`)."""
    config: MDIConfig
    """With ``bc`` resolved (never None here)."""
    context_early_stop: float | None = None
    """The pairs' early-stop threshold: it cuts the BC rollout of a mapper's context, as in the pairs."""


def head_folder(method: str, shot: str) -> str:
    """The name of the folder of the heads a method was tested with at one shot."""
    if shot not in SHOTS:
        raise UserError(f"no MDI heads for shot {shot!r}: expected one of {SHOTS}")
    return f"mdi-{method}-{shot}"


def _cosine(task: Task, traj: Trajectory) -> tuple[float | None, float | None]:
    """Accumulated and per-action cosine distance of a rollout, measured as the early stop does
    (with its dead zone on short expert labels); None for discrete actions."""
    if task.is_discrete:
        return None, None
    # the meter's threshold is irrelevant here: only its totals are read
    meter = CosineEarlyStop()
    for action, label in zip(traj.learner_actions, traj.expert_labels):
        meter.update(action, label)
    return meter.total, meter.mean


def evaluate_mdi_seed(job: MDIJob) -> dict[str, Any]:
    """Run Table 6 for the job's methods on one seed; returns ``seed``, ``entries``
    (``{method: [row]}``) and ``heads`` (``{(method, shot): head vector}``)."""
    config, seed = job.config, job.seed
    fit, refit = seeded(config.bc, seed), seeded(config.dagger_bc, seed)
    entries: dict[str, list[dict[str, Any]]] = {}
    heads: dict[tuple[str, str], np.ndarray] = {}
    with SeedLearner(job.task, job.pistar, seed, head_init_seed=config.bc.head_init_seed(seed)) as learner:
        # steps 1-2: the demonstration and w_BC; DAgger's own start is the seed's fresh Xavier head
        xavier = learner.head()
        demo = demonstration(learner)
        data = demo.to_dataset()
        w_bc = bc_head(learner, data, fit)
        # steps 3-4: each method's saved initialisation
        mappers = {method: cached_mapper(file) for method, file in job.mappers.items()}
        context = None
        if any(mapper.needs_context for mapper in mappers.values()):
            rolled = learner.roll(w_bc, early_stop=job.context_early_stop)
            context = seed_context(learner.cache, data, rolled.to_dataset())
        inits = {method: map_head(mapper, w_bc, context) for method, mapper in mappers.items()}
        if "dagger-bc-init" in job.methods:
            inits["dagger-bc-init"] = w_bc
        # step 5: each initialisation refitted on the demonstration; for DAgger that is step 2's fit
        # itself (the Xavier head, the same data and settings), so w_BC is not fitted twice
        one_shot_heads = {"dagger-xavier": w_bc} | {
            method: one_shot(learner, init, data, fit) for method, init in inits.items()
        }
        inits["dagger-xavier"] = xavier
        for method in job.methods:
            heads[method, "oneshot"] = one_shot_heads[method]
            # steps 6-7: the one-shot test
            first = final = learner.roll(one_shot_heads[method], early_stop=config.early_stop)
            ran = not first.success
            if ran:
                # steps 8-9: one DAgger round labels the one-shot test's states and refits from the
                # saved initialisation (Table 6) or from the one-shot head
                start = inits[method] if config.dagger_init == "saved" else one_shot_heads[method]
                (round_,) = dagger_rounds(
                    learner,
                    start=start,
                    first_rollout=first,
                    demo=demo,
                    rounds=1,
                    fit=refit,
                    early_stop=config.early_stop,
                    origin=start,
                )
                heads[method, "twoshot"], final = round_.head, round_.rollout
            cosine_total, cosine_mean = _cosine(job.task, final)
            entries[method] = [
                {
                    "method": method,
                    "seed": seed,
                    "one_shot_success": bool(first.success),
                    "one_shot_reward": float(first.reward),
                    "one_shot_steps": int(first.steps),
                    "one_shot_early_stopped": bool(first.early_stopped),
                    "two_shot_run": ran,
                    "two_shot_success": bool(final.success),
                    "two_shot_reward": float(final.reward) if ran else None,
                    "two_shot_steps": int(final.steps) if ran else None,
                    "two_shot_early_stopped": bool(final.early_stopped) if ran else None,
                    "demo_steps": len(data),
                    "expert_queries": len(data) + (first.expert_queries if ran else 0),
                    "cosine_total": cosine_total,
                    "cosine_per_action": cosine_mean,
                }
            ]
    return {"seed": seed, "entries": entries, "heads": heads}


def _check_inputs(task: Task, layout: RunLayout, config: MDIConfig) -> None:
    if config.early_stop is not None and not isinstance(task.learner_action_space, gym.spaces.Box):
        raise UserError(
            f"mdi.early_stop={config.early_stop} needs displacement (Box) actions, but task {task.name!r} has "
            f"{task.learner_action_space}; set mdi.early_stop to null"
        )
    head_size = cached_pistar(str(layout.pistar)).head_size
    for kind in config.kinds.values():
        path = layout.mapper(kind)
        if not path.is_file():
            raise UserError(
                f"MDI mapper not found at {path}; run `metadagger train-mapper --out {layout.root} --kind {kind}` first"
            )
        mapper_dim = load_mapper(path).dim
        if mapper_dim != head_size:
            raise UserError(
                f"the mapper at {path} maps heads of length {mapper_dim}, but pi*'s head has {head_size}; "
                "train the mapper on this run's pairs (metadagger train-mapper)"
            )


def mdi_stamps(
    task: Task, layout: RunLayout, config: MDIConfig, context_early_stop: float | None = None
) -> dict[str, Stamp]:
    """What each MDI method's rows are made from: the protocol's settings, pi* and its initialiser
    (and, for an initialiser that reads the seed's context, the early stop of its BC rollout)."""
    common = {
        "protocol": "mdi",
        **kernel_stamp(),
        **task_stamp(task),
        **stamp_of(config, drop=("seeds", "mapper", "controls")),
        **lanes_stamp(config.lanes),
        "pistar_fingerprint": file_fingerprint(layout.pistar),
    }
    kinds = config.kinds

    def own(method: str) -> dict[str, Any]:
        if method not in kinds:
            return {}
        return {
            "mapper_fingerprint": file_fingerprint(layout.mapper(kinds[method])),
            **context_inputs(kinds[method], context_early_stop),
        }

    return {method: {**common, **own(method)} for method in config.methods}


def evaluate_mdi(
    task: Task,
    layout: RunLayout,
    config: MDIConfig,
    options: StageOptions = StageOptions(),
    *,
    context_early_stop: float | None = None,
) -> list[dict[str, Any]]:
    """Run the MDI protocol on the missing (seed, method) rows of ``config``.

    Args:
        task: the task (its learner env is rolled out).
        layout: the run folder; results go to ``eval/mdi.csv``, ``eval/mdi_rows.jsonl`` (the resume
            log) and ``eval/heads/mdi-<method>-<shot>/``; pi* and the mappers are read from it.
        config: seeds, fits (``bc`` resolved), early stop, initialisers.
        options: rebuild (redo rows made from another pi*, mapper or settings; else they are an
            error), executor, workers, progress.
        context_early_stop: the pairs' early-stop threshold, which cuts the BC rollout of an
            initialiser's context (:func:`metadagger.metal_dagger.method.seed_context`).

    Returns:
        The rows (:data:`MDI_FIELDS`) of every seed of ``config``, by seed then in
        ``config.methods`` order.
    """
    if config.bc is None:
        raise UserError("mdi.bc is unresolved; build the run config with RunConfig (it takes pairs.bc)")
    _check_inputs(task, layout, config)
    stamps = mdi_stamps(task, layout, config, context_early_stop)
    log = RowLog(layout.eval_log("mdi"))
    todo = plan(
        config.seeds,
        stamps,
        log,
        rebuild=options.rebuild,
        called="MDI evaluation",
        fix=f"run `metadagger evaluate --out {layout.root} --protocol mdi --rebuild` to redo it, or `metadagger "
        "reproduce`",
    )
    jobs = [
        MDIJob(
            task=task,
            pistar=str(layout.pistar),
            seed=p.seed,
            methods=p.methods,
            config=config,
            mappers={
                m: MapperFile(str(layout.mapper(config.kinds[m])), stamps[m]["mapper_fingerprint"])
                for m in p.methods
                if m in config.kinds
            },
            context_early_stop=context_early_stop,
        )
        for p in todo
    ]

    def save(result: dict[str, Any]) -> None:
        for (method, shot), head in result["heads"].items():
            head = torch.from_numpy(np.array(head))  # a copy: arrays from Ray workers are read-only
            save_tensors(layout.heads(head_folder(method, shot)) / f"{result['seed']}.safetensors", {"head": head})

    work, units = in_blocks(evaluate_mdi_seed, jobs, config.lanes, options.workers)
    drive(work, units, log=log, stamps=stamps, save=save, options=options, desc="mdi")
    rows = log.rows(config.seeds, stamps)
    write_csv(layout.eval_table("mdi"), rows, fields=MDI_FIELDS)
    return rows
