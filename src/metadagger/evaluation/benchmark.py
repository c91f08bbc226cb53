"""Success against expert queries: DAgger, gated DAgger baselines and MetaL DAgger on one chart.

Every method starts where the pairs start: pi*'s frozen trunk and a head fitted by BC on the
seed's expert demonstration (w_BC). A *query* is one expert label of one state: each
demonstration step, and each visited state a DAgger round chooses to label; the part of the
action the environment's expert always drives (CarRacing's gas and brake, Fetch's gripper) is not
a query. Per seed, with rows ``(method, setting, demo_fraction, seed)``:

- ``bc``: w_BC rolled out (the demonstration's queries only).
- ``mdm-<kind>``: each mapper kind applied to w_BC (MDM: no further query); the controls (pi*'s
  head, mean-DA) never read the demonstration and are charged no query at all.
- ``dagger``: rounds 1..R of the pairs' DAgger (every visited state labelled), one row per round
  (setting = the round), with cumulative queries.
- ``dagger-random``, ``dagger-ensemble``, ``dagger-safe``, ``dagger-novelty``, ``dagger-thrifty``,
  ``dagger-conformal``: the same R rounds, labelling only the states their gate
  (:mod:`metadagger.imitation.gates`) selects; one row per setting of the gate's grid (the random
  share p, the score quantile, the target rate or the miscoverage), after round R.
- ``dagger-mdi``, ``dagger-bc-init``, ``dagger-xavier`` (runs with an ``mdi`` section): Table 6's
  one-shot and two-shot tests (settings ``one-shot``, ``two-shot``).

With ``demo_fractions`` below 1, BC, the learned MDM kinds and the gated settings run again from
the demonstration's first share of steps (:func:`~metadagger.metal.method.demonstration_share`),
so that the chart shows whether mapping can replace part of the demonstration.

A row's outcome is one rollout of the policy after that many rounds (the rollout that also starts
the next round, which is deterministic, so nothing is rolled out twice).
"""

from __future__ import annotations

import math
from contextlib import ExitStack
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from metadagger.errors import UserError
from metadagger.evaluation.mdi import MDIConfig, MDIJob, evaluate_mdi_seed
from metadagger.evaluation.methods import (
    BC_REFIT,
    GATED,
    MDI_METHODS,
    MDM_PREFIX,
    METHODS,
    GateKey,
    MapperKey,
    MethodKey,
    RefitKey,
    RoundKey,
    ShotKey,
    reads_demonstration,
    with_demo_fractions,
)
from metadagger.evaluation.paired import paired_comparison
from metadagger.evaluation.rows import write_csv
from metadagger.evaluation.tables import method_label
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.gates import Gate, make_gate
from metadagger.imitation.lanes import Lanes, check_lanes
from metadagger.imitation.metrics import summarize
from metadagger.imitation.rollouts import Trajectory
from metadagger.mapping.mappers import MapperFile, cached_mapper
from metadagger.mapping.registry import control_names
from metadagger.metal.method import (
    Round,
    SeedLearner,
    bc_head,
    dagger_rounds,
    demonstration,
    demonstration_share,
    map_head,
    run_steps,
    seed_context,
    seeded,
)
from metadagger.runfolder.driver import RowLog, SeedJob, StageOptions, Stamp, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import write_json
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.plotting import draw_figure, interval_errors, plt, save_figure
from metadagger.utils.yaml_config import LATER_OPTION

#: Columns of ``benchmark/queries.csv``.
FIELDS = ("method", "setting", "demo_fraction", "seed", "success", "reward", "steps", "expert_queries")


@dataclass(frozen=True)
class BenchmarkConfig:
    """Which methods the benchmark runs, on which unseen seeds, with which gate grids."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or the pairs)."""
    methods: tuple[str, ...] = ("bc", "mdm", "dagger", BC_REFIT, *GATED)
    """``bc``, ``mdm`` (every kind of ``evaluate.methods``), ``dagger``, ``bc-refit`` (w_BC refitted
    as DAgger refits it, on the demonstration alone: a control), the gated methods, and ``mdi``
    (the MDI protocol's methods; runs with an ``mdi`` section)."""
    grids: dict = field(
        default_factory=lambda: {
            "dagger-random": [0.05, 0.2, 0.5],
            "dagger-ensemble": [0.5, 0.8, 0.95],
            "dagger-safe": [0.5, 0.8, 0.95],
            "dagger-novelty": [0.5, 0.8, 0.95],
            "dagger-thrifty": [0.025, 0.1, 0.25],
            "dagger-conformal": [0.05, 0.2, 0.5],
        }
    )
    """Each gated method's sweep: the random share p; the score quantile above which a state is
    labelled (about 1 - quantile of each round's states); ThriftyDAgger's target rate of each of
    its two tests (their union labels at most twice it); the conformal gate's miscoverage (about
    that share of the first round's states). The defaults span label shares of about 50%, 20% and
    5%, fixed before any benchmark ran (not tuned on any seeds)."""
    ensemble_heads: int = 5
    """K, the bootstrap heads of the ensemble and ThriftyDAgger gates."""
    novelty_k: int = 1
    """k, the neighbour of the novelty and conformal gates."""
    demo_fractions: tuple[float, ...] = (1.0,)
    """Shares of the demonstration's steps that BC, the learned MDM kinds and the gated settings
    start from, in (0, 1], 1 (the whole demonstration) among them; plain DAgger and MDI always
    start from the whole one."""
    lanes: int = field(default=1, metadata=LATER_OPTION)
    """Episodes of a seed stepped in lockstep, one trunk forward per step for all of them, at this
    batch shape (:mod:`metadagger.imitation.lanes`); 1 rolls each episode out alone. The numbers
    depend on it (a batch of one rounds the last bits otherwise), never on the workers."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("benchmark.seeds must not be empty")
        known = tuple(METHODS)
        if not self.methods:
            raise UserError(f"benchmark.methods must not be empty; allowed: {', '.join(known)}")
        unknown = [m for m in self.methods if m not in known]
        if unknown:
            raise UserError(f"benchmark.methods has unknown method(s) {unknown}; allowed: {', '.join(known)}")
        bad = sorted(set(self.grids) - set(GATED))
        if bad:
            raise UserError(f"benchmark.grids has unknown method(s) {bad}; allowed: {', '.join(GATED)}")
        for method in self.methods:
            if method in GATED:
                grid = self.grids.get(method)
                if not grid:
                    raise UserError(
                        f"benchmark.grids.{method} is missing or empty; give its settings, e.g. [0.5, 0.8, 0.95]"
                    )
                for value in grid:
                    make_gate(GATED[method], value, **self.gate_options(method))  # range checks now, not hours later
        if (
            1.0 not in self.demo_fractions
            or any(not 0.0 < f <= 1.0 for f in self.demo_fractions)
            or len(set(self.demo_fractions)) != len(self.demo_fractions)
        ):
            raise UserError(
                f"benchmark.demo_fractions must be distinct shares in (0, 1] with 1 among them, got "
                f"{list(self.demo_fractions)}; e.g. [0.25, 0.5, 1.0]"
            )
        check_lanes("benchmark.lanes", self.lanes)
        if self.ensemble_heads < 2 or self.novelty_k < 1:
            raise UserError(
                f"benchmark.ensemble_heads must be >= 2 and benchmark.novelty_k >= 1, got "
                f"{self.ensemble_heads} and {self.novelty_k}"
            )

    def gate_options(self, method: str) -> dict[str, Any]:
        """Keyword options of a gated method's gate."""
        return {
            "dagger-ensemble": {"K": self.ensemble_heads},
            "dagger-novelty": {"k": self.novelty_k},
            "dagger-thrifty": {"K": self.ensemble_heads},
            "dagger-conformal": {"k": self.novelty_k},
        }.get(method, {})


@dataclass(frozen=True)
class BenchmarkJob(SeedJob):
    """One seed's benchmark; its ``methods`` are the ids of its ``keys``."""

    keys: tuple[MethodKey, ...]
    """The method keys this job runs (:mod:`metadagger.evaluation.methods`)."""
    mappers: dict[str, MapperFile]
    """Mapper file of every MDM kind this job runs."""
    config: BenchmarkConfig
    rounds: int
    """R: the DAgger rounds of the pairs."""
    bc: BCConfig
    dagger_bc: BCConfig
    early_stop: float | None
    mdi: MDIConfig | None
    """The run's MDI protocol (``bc`` resolved) when the job runs its methods."""


def method_keys(config: BenchmarkConfig, *, rounds: int, kinds: tuple[str, ...], mdi: bool) -> list[MethodKey]:
    """Every method key the benchmark rows of one seed are made of, in table order."""
    keys = [key for method in config.methods for key in METHODS[method](rounds, kinds, config.grids, mdi)]
    return with_demo_fractions(keys, config.demo_fractions)


def _row(key: MethodKey, seed: int, traj: Trajectory, queries: int) -> dict[str, Any]:
    return {
        "method": key.method,
        "setting": key.setting,
        "demo_fraction": key.demo_fraction,
        "seed": seed,
        "success": bool(traj.success),
        "reward": float(traj.reward),
        "steps": int(traj.steps),
        "expert_queries": int(queries),
    }


def benchmark_seed(job: BenchmarkJob) -> dict[str, Any]:
    """Run the job's method keys on one seed; returns ``seed`` and ``entries`` (by key id).

    With ``config.lanes`` above 1 every chain of rollouts (each gate setting's rounds, DAgger's,
    each mapper's head, each refit) steps in lockstep lanes (:mod:`metadagger.imitation.lanes`).
    """
    seed, keys = job.seed, job.keys
    rows: dict[MethodKey, dict[str, Any]] = {}
    with ExitStack() as stack:
        learner = stack.enter_context(
            SeedLearner(job.task, job.groundtruth, seed, head_init_seed=job.bc.head_init_seed(seed))
        )
        lanes = None
        if job.config.lanes > 1:
            lanes = stack.enter_context(Lanes(job.task, learner.policy.net, width=job.config.lanes))
        fresh = learner.head()
        [demo] = run_steps(learner, [demonstration], lanes)
        for fraction in sorted({key.demo_fraction for key in keys}, reverse=True):
            mine = [key for key in keys if key.demo_fraction == fraction]
            share = demonstration_share(demo, fraction)
            [start] = run_steps(learner, [partial(_start, job, fresh, share, mine)], lanes)
            for found in run_steps(learner, _row_steps(job, start, mine), lanes):
                rows.update(found)
    shots = [key for key in keys if isinstance(key, ShotKey)]
    if job.mdi is not None and shots:
        rows.update(_mdi_rows(job, shots))
    return {"seed": seed, "entries": {key.id: [rows[key]] for key in keys if key in rows}}


@dataclass(frozen=True)
class _Start:
    """Where every row of one demonstration share starts: w_BC and its rollout."""

    demo: Trajectory
    w_bc: np.ndarray
    first: Trajectory
    """w_BC's rollout under the pairs' early stop: the BC row, the context's rollout and DAgger's first round."""
    context: np.ndarray | None
    """The seed's context, where a mapper reads one."""


def _start(
    job: BenchmarkJob, fresh: np.ndarray, demo: Trajectory, keys: list[MethodKey], learner: SeedLearner
) -> _Start:
    """w_BC fitted on ``demo`` from the learner's fresh head, rolled out; the context if a mapper needs it."""
    data = demo.to_dataset()
    learner.load(fresh)
    w_bc = bc_head(learner, data, seeded(job.bc, job.seed))
    first = learner.roll(w_bc, early_stop=job.early_stop)
    needs_context = any(
        cached_mapper(job.mappers[key.kind]).needs_context for key in keys if isinstance(key, MapperKey)
    )
    context = seed_context(learner.cache, data.obs, first.obs) if needs_context else None
    return _Start(demo, w_bc, first, context)


def _row_steps(
    job: BenchmarkJob, start: _Start, keys: list[MethodKey]
) -> list[Callable[[SeedLearner], dict[MethodKey, dict[str, Any]]]]:
    """One step per chain of rollouts that makes rows of ``keys`` (all but MDI's) from ``start``, in table order."""
    seed, queries = job.seed, len(start.demo.obs)
    steps: list[Callable[[SeedLearner], dict[MethodKey, dict[str, Any]]]] = []
    bc_rows = {
        key: _row(key, seed, start.first, queries) for key in keys if type(key) is MethodKey and key.method == "bc"
    }
    steps.append(lambda learner: bc_rows)
    for key in (k for k in keys if isinstance(k, MapperKey)):
        steps.append(partial(_mapper_row, job, start, key))
    by_round = {key.round: key for key in keys if isinstance(key, RoundKey)}
    if by_round:
        steps.append(partial(_dagger_rows, job, start, by_round))
    for key in (k for k in keys if isinstance(k, GateKey)):
        steps.append(partial(_gate_row, job, start, key))
    for key in (k for k in keys if isinstance(k, RefitKey)):
        steps.append(partial(_refit_row, job, start, key))
    return steps


def _mapper_row(
    job: BenchmarkJob, start: _Start, key: MapperKey, learner: SeedLearner
) -> dict[MethodKey, dict[str, Any]]:
    head = map_head(cached_mapper(job.mappers[key.kind]), start.w_bc, start.context)
    queries = len(start.demo.obs) if reads_demonstration(key) else 0
    return {key: _row(key, job.seed, learner.roll(head, early_stop=job.early_stop), queries)}


def _rounds(job: BenchmarkJob, start: _Start, learner: SeedLearner, gate: Gate | None) -> Iterator[Round]:
    return dagger_rounds(
        learner,
        start=start.w_bc,
        first=start.first,
        demo=start.demo,
        rounds=job.rounds,
        fit=seeded(job.dagger_bc, job.seed),
        gate=gate,
        early_stop=job.early_stop,
    )


def _dagger_rows(
    job: BenchmarkJob, start: _Start, by_round: dict[int, RoundKey], learner: SeedLearner
) -> dict[MethodKey, dict[str, Any]]:
    return {
        by_round[r.index]: _row(by_round[r.index], job.seed, r.rollout, r.queries)
        for r in _rounds(job, start, learner, None)
        if r.index in by_round
    }


def _gate_row(job: BenchmarkJob, start: _Start, key: GateKey, learner: SeedLearner) -> dict[MethodKey, dict[str, Any]]:
    gate = make_gate(key.gate, key.value, **job.config.gate_options(key.method))
    for last in _rounds(job, start, learner, gate):
        pass  # only the last round's rollout makes the row: the earlier ones are let go as they end
    return {key: _row(key, job.seed, last.rollout, last.queries)}


def _refit_row(
    job: BenchmarkJob, start: _Start, key: RefitKey, learner: SeedLearner
) -> dict[MethodKey, dict[str, Any]]:
    # DAgger's refits (continuing from w_BC, DAgger's fit) on the demonstration alone
    data = start.demo.to_dataset()
    learner.load(start.w_bc)
    for index in range(1, key.rounds + 1):
        bc_head(learner, data, seeded(job.dagger_bc, job.seed), what=f"BC's refit {index}")
    return {key: _row(key, job.seed, learner.roll(early_stop=job.early_stop), len(data))}


def _mdi_rows(job: BenchmarkJob, keys: list[ShotKey]) -> dict[MethodKey, dict[str, Any]]:
    """Table 6's one- and two-shot outcomes of DAgger-MDI, DAgger-BC and DAgger on this seed."""
    assert job.mdi is not None
    mdi_job = MDIJob(
        task=job.task,
        groundtruth=job.groundtruth,
        seed=job.seed,
        methods=tuple(MDI_METHODS),
        mappers={"dagger-mdi": job.mappers["mdi"]},
        config=job.mdi,
        context_early_stop=job.early_stop,
    )
    outcomes = {method: rows[0] for method, rows in evaluate_mdi_seed(mdi_job)["entries"].items()}
    out: dict[MethodKey, dict[str, Any]] = {}
    for key in keys:
        r = outcomes[key.mdi_method]
        two = key.shot == "twoshot" and r["two_shot_run"]
        out[key] = {
            "method": key.method,
            "setting": key.setting,
            "demo_fraction": key.demo_fraction,
            "seed": job.seed,
            "success": r["two_shot_success"] if key.shot == "twoshot" else r["one_shot_success"],
            "reward": r["two_shot_reward"] if two else r["one_shot_reward"],
            "steps": r["two_shot_steps"] if two else r["one_shot_steps"],
            "expert_queries": r["expert_queries"] if key.shot == "twoshot" else r["demo_steps"],
        }
    return out


def benchmark_stamps(
    task: Task,
    layout: RunLayout,
    job_settings: dict[str, Any],
    config: BenchmarkConfig,
    keys: list[MethodKey],
    mdi: MDIConfig | None,
    mdi_mapper: str | None,
) -> dict[str, Stamp]:
    """What each method key's rows are made from: the shared fits, pi*, and the method's own inputs."""
    common = {
        "protocol": "benchmark",
        **kernel_stamp(),
        **task_stamp(task),
        **job_settings,
        "groundtruth_fingerprint": file_fingerprint(layout.groundtruth),
    }
    stamps: dict[str, Stamp] = {}
    for key in keys:
        own: dict[str, Any] = {} if key.demo_fraction == 1.0 else {"demo_fraction": key.demo_fraction}
        if isinstance(key, MapperKey):
            own = {
                **own,
                "mapper_fingerprint": file_fingerprint(layout.mapper(key.kind)),
                **({} if reads_demonstration(key) else {"charged": "no query"}),
            }
        elif isinstance(key, GateKey):
            own = {**own, "gate": config.gate_options(key.method)}
        elif isinstance(key, ShotKey) and mdi is not None and mdi_mapper is not None:
            own = {
                "mdi": stamp_of(mdi, drop=("seeds", "controls")),
                "mapper_fingerprint": file_fingerprint(layout.mapper(mdi_mapper)),
            }
        stamps[key.id] = {**common, **own}
    return stamps


def run_benchmark(
    task: Task,
    layout: RunLayout,
    config: BenchmarkConfig,
    *,
    rounds: int,
    bc: BCConfig,
    dagger_bc: BCConfig,
    early_stop: float | None,
    kinds: tuple[str, ...],
    mdi: MDIConfig | None,
    meta_queries: dict[str, int],
    options: StageOptions = StageOptions(),
) -> list[dict[str, Any]]:
    """Run the missing rows of the benchmark; write ``queries.csv``, ``summary.json``, then the
    figure (a figure that fails is a warning: the rows and the summary are on disk before it).

    Args:
        task: the task.
        layout: the run folder (pi* and mappers are read from it; results go to ``benchmark/``).
        config: seeds, methods and gate grids.
        rounds: R, the pairs' DAgger rounds; ``bc``, ``dagger_bc``, ``early_stop``: the pairs' fits
            and early stop, so every method starts where the pairs start.
        kinds: the mapper kinds MDM runs with.
        mdi: the run's MDI protocol (``bc`` resolved), or None.
        meta_queries: expert queries spent on meta-training (``pistar``, ``pairs``), for the report.
        options: rebuild (redo rows made from other inputs; else they are an error), executor,
            workers, progress: as for every stage.

    Raises:
        UserError: ``config.methods`` has ``mdi`` but the run has no MDI protocol; or, without
            ``rebuild``, rows made from other inputs.
    """
    with_mdi = "mdi" in config.methods
    if with_mdi and mdi is None:
        raise UserError(
            f"benchmark method mdi needs an mdi section, but run {layout.root} has none; "
            "drop mdi from --methods (or benchmark.methods), or add an mdi section"
        )
    keys = method_keys(config, rounds=rounds, kinds=kinds, mdi=with_mdi)
    settings = {"rounds": rounds, "bc": stamp_of(bc), "dagger_bc": stamp_of(dagger_bc), "early_stop": early_stop}
    if config.lanes != 1:  # a later option: rows made alone stay current
        settings["lanes"] = config.lanes
    stamps = benchmark_stamps(
        task, layout, settings, config, keys, mdi if with_mdi else None, mdi.mapper if with_mdi else None
    )
    log = RowLog(layout.benchmark_log)
    todo = plan(
        config.seeds,
        stamps,
        log,
        rebuild=options.rebuild,
        what="the benchmark",
        fix=f"run `metadagger benchmark --out {layout.root} --rebuild` to redo it, or `metadagger reproduce`",
    )
    # each mapper file as its stamps fingerprinted it: a worker refuses other bytes
    mappers = {
        key.kind: MapperFile(str(layout.mapper(key.kind)), stamps[key.id]["mapper_fingerprint"])
        for key in keys
        if isinstance(key, MapperKey)
    }
    mappers.update(
        {
            "mdi": MapperFile(str(layout.mapper(mdi.mapper)), stamps[key.id]["mapper_fingerprint"])
            for key in keys
            if isinstance(key, ShotKey) and mdi is not None
        }
    )
    by_id = {key.id: key for key in keys}
    jobs = [
        BenchmarkJob(
            task=task,
            groundtruth=str(layout.groundtruth),
            seed=p.seed,
            methods=p.methods,
            keys=tuple(by_id[m] for m in p.methods),
            mappers=mappers,
            config=config,
            rounds=rounds,
            bc=bc,
            dagger_bc=dagger_bc,
            early_stop=early_stop,
            mdi=mdi if with_mdi else None,
        )
        for p in todo
    ]
    drive(benchmark_seed, jobs, log=log, stamps=stamps, options=options, desc="benchmark")
    rows = log.rows(config.seeds, stamps)
    write_csv(layout.benchmark_table, rows, fields=FIELDS)
    summary = summarize_benchmark(rows, meta_queries)
    write_json(layout.benchmark_summary, summary)
    draw_figure(layout.benchmark_figure, lambda path: plot_queries(summary, path))
    return rows


#: What a summary entry is keyed by: (method, setting, demonstration share).
Group = tuple[str, str, float]


def summarize_benchmark(rows: list[dict[str, Any]], meta_queries: dict[str, int]) -> dict[str, Any]:
    """Per (method, setting, demonstration share): success rate with its 95% Wilson interval, mean
    reward and mean queries per seed; the queries spent on meta-training; the references
    (:func:`references`) and every method's paired comparison with each (:func:`comparisons`)."""
    groups: dict[Group, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], str(r["setting"]), float(r["demo_fraction"])), []).append(r)
    entries = []
    for (method, setting, fraction), group in groups.items():
        s = summarize(group)
        entries.append(
            {
                "method": method,
                "setting": setting,
                "demo_fraction": fraction,
                "seeds": s["episodes"],
                "successes": s["successes"],
                "success_rate": s["success_rate"],
                "success_ci_low": s["success_ci_low"],
                "success_ci_high": s["success_ci_high"],
                "mean_reward": s["mean_reward"],
                "mean_queries": s["expert_queries"] / s["episodes"],
            }
        )
    refs = references(entries)
    return {
        "entries": entries,
        "meta_training_queries": dict(meta_queries),
        "references": refs,
        "comparisons": comparisons(groups, refs),
    }


def references(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What every method is compared with: each MDM control, BC refitted as DAgger (``bc-refit``),
    and the best gate (the gated DAgger setting with the highest success, the fewest queries on a
    tie), as ``method``/``setting``/``demo_fraction``."""
    controls = {MDM_PREFIX + name for name in control_names()} | {BC_REFIT}
    refs = [e for e in entries if e["method"] in controls]
    gates = [e for e in entries if e["method"] in GATED]
    if gates:
        refs.append(max(gates, key=lambda e: (e["success_rate"], -e["mean_queries"])))
    return [{"method": e["method"], "setting": e["setting"], "demo_fraction": e["demo_fraction"]} for e in refs]


def comparisons(groups: dict[Group, list[dict[str, Any]]], refs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every (method, setting, demonstration share) against every reference but itself, paired on
    the seeds both ran (:func:`metadagger.evaluation.paired.paired_comparison`)."""
    by_seed = {key: {r["seed"]: r for r in group} for key, group in groups.items()}
    out = []
    for ref in refs:
        against = (ref["method"], ref["setting"], ref["demo_fraction"])
        other = by_seed[against]
        for (method, setting, fraction), mine in by_seed.items():
            if (method, setting, fraction) == against:
                continue
            seeds = sorted(set(mine) & set(other))
            if not seeds:
                continue
            a, b = [mine[s] for s in seeds], [other[s] for s in seeds]
            stats = paired_comparison(
                [r["success"] for r in a], [r["success"] for r in b], [r["reward"] for r in a], [r["reward"] for r in b]
            )
            out.append(
                {
                    "method": method,
                    "setting": setting,
                    "demo_fraction": fraction,
                    "against": ref["method"],
                    "against_setting": ref["setting"],
                    "against_demo_fraction": ref["demo_fraction"],
                    **stats,
                }
            )
    return out


#: Marker shapes, cycled with the colours so that methods stay apart past ten of them.
MARKERS = ("o", "s", "D", "^", "v", "<", ">", "p", "h", "*")
#: Sideways spread between points at one query count, as a share of the x axis's decades.
DODGE = 0.012
#: Most ticks placed at the points' own query counts; more become a 1-2-5 sequence.
MAX_TICKS = 8


def query_ticks(values: Sequence[float]) -> list[float]:
    """Ticks of the query axis: the points' own counts (those within 4% of a smaller one left out)
    when there are at most :data:`MAX_TICKS`, else the 1-2-5 sequence across their range."""
    ticks: list[float] = []
    for v in sorted(set(values)):
        if not ticks or v > 1.04 * ticks[-1]:
            ticks.append(v)
    if len(ticks) <= MAX_TICKS:
        return ticks
    low, high = math.floor(math.log10(ticks[0])), math.ceil(math.log10(ticks[-1]))
    steps = [m * 10.0**e for e in range(low, high + 1) for m in (1, 2, 5)]
    inside = [t for t in steps if ticks[0] <= t <= ticks[-1]]
    return inside if len(inside) >= 2 else [ticks[0], ticks[-1]]


def dodge(xs: Sequence[float], step: float) -> list[float]:
    """``xs`` spread sideways where several are equal: the k points at one value move to
    ``value * 10 ** (step * (j - (k - 1) / 2))``, j = 0..k-1 in the order given (log axes)."""
    groups: dict[float, list[int]] = {}
    for i, x in enumerate(xs):
        groups.setdefault(x, []).append(i)
    out = list(xs)
    for x, members in groups.items():
        for j, i in enumerate(members):
            out[i] = x * 10.0 ** (step * (j - (len(members) - 1) / 2))
    return out


def _tick_label(value: float) -> str:
    return f"{value:.0f}" if value >= 100 else f"{value:.3g}"


def plot_queries(summary: dict[str, Any], path: Path) -> Path:
    """Success (95% intervals) against mean expert queries per seed, one line per method, log x.

    Ticks sit at the points' query counts (:func:`query_ticks`); points of several methods at one
    count (BC and every MDM method spend only the demonstration's queries) are spread sideways
    (:func:`dodge`) so that none hides another. Methods that ask no query (the MDM controls) sit
    at a tick "0", half the smallest count left of it.
    """
    by_method: dict[str, list[dict[str, Any]]] = {}
    for e in summary["entries"]:
        by_method.setdefault(e["method"], []).append(e)
    points = [
        (method, e) for method, group in by_method.items() for e in sorted(group, key=lambda e: e["mean_queries"])
    ]
    counts = [float(e["mean_queries"]) for _, e in points]
    zero_at = min((q for q in counts if q > 0), default=2.0) / 2
    xs = [q if q > 0 else zero_at for q in counts]
    span = math.log10(max(xs) / min(xs))
    shown = dodge(xs, DODGE * max(span, 0.5))
    fig, ax = plt.subplots(figsize=(8.5, 4.8), layout="constrained")
    for i, method in enumerate(by_method):
        mine = [k for k, (m, _) in enumerate(points) if m == method]
        entries = [points[k][1] for k in mine]
        rates = [e["success_rate"] for e in entries]
        err = interval_errors(rates, [e["success_ci_low"] for e in entries], [e["success_ci_high"] for e in entries])
        ax.errorbar(
            [shown[k] for k in mine],
            rates,
            yerr=err,
            marker=MARKERS[i % len(MARKERS)],
            ms=4,
            capsize=2,
            lw=1.2,
            label=method_label(method),
        )
    ax.set_xscale("log")
    pad = 10.0 ** max(0.06 * span, 0.08)
    ax.set_xlim(min(shown) / pad, max(shown) * pad)
    ticks = query_ticks([x for x, q in zip(xs, counts) if q > 0] or [zero_at])
    labels = [_tick_label(t) for t in ticks]
    if 0 in counts:
        ticks, labels = [zero_at, *ticks], ["0", *labels]
    ax.set_xticks(ticks, labels)
    ax.minorticks_off()
    shared = len(set(xs)) < len(xs)
    ax.set_xlabel(
        "mean expert queries per seed (log)" + ("; points at one count are spread sideways" if shared else "")
    )
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)
