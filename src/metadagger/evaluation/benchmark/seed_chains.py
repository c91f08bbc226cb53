"""One seed of the query benchmark: the chains of rollouts that make its rows.

Every row of a seed starts where the pairs start (:class:`_Start`): the demonstration (or its
first share), w_BC fitted on it, w_BC's rollout. Each group of keys that one chain of rollouts
makes (:attr:`~metadagger.evaluation.benchmark.methods.MethodKey.chain`) is one call of the chain for its
key type in :data:`CHAINS`; with ``benchmark.lanes`` above 1 the chains step in lockstep lanes.
The stage around it (configs, stamps, resume, tables) is :mod:`metadagger.evaluation.benchmark.protocol`.
"""

from __future__ import annotations

import dataclasses
from contextlib import ExitStack
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Callable, Iterator

import numpy as np
import torch

from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.coverage import coverage_gap
from metadagger.evaluation.benchmark.ledger import demonstration_record, round_record, tally
from metadagger.evaluation.benchmark.methods import (
    MDI_MAPPER,
    MDI_METHODS,
    BCKey,
    DartKey,
    DisagreeKey,
    GateKey,
    MapperKey,
    MethodKey,
    PriorGateKey,
    PriorKey,
    PriorRoundKey,
    RefitKey,
    RoundKey,
    ShotKey,
)
from metadagger.evaluation.mdi import MDIConfig, MDIJob, evaluate_mdi_seed
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.data import Dataset
from metadagger.imitation.gate_registry import GATED_PREFIX, make_gate
from metadagger.imitation.gates import Gate
from metadagger.imitation.head_fits import Prior
from metadagger.imitation.lanes import Lanes
from metadagger.imitation.reading_gates import DisagreementGate
from metadagger.imitation.rollouts import Trajectory
from metadagger.mapping.mappers import MapperFile, cached_mapper
from metadagger.mapping.priors import ZERO, HeadPrior, mean_head
from metadagger.metal_dagger.controls import dart_rounds, expert_loss, held_out
from metadagger.metal_dagger.method import (
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
from metadagger.runfolder.driver import SeedJob


@dataclass(frozen=True)
class BenchmarkJob(SeedJob):
    """One seed's benchmark; its ``methods`` are the ids of its ``keys``."""

    keys: tuple[MethodKey, ...]
    """The method keys this job runs (:mod:`metadagger.evaluation.benchmark.methods`)."""
    mappers: dict[str, MapperFile]
    """Mapper file of every mapper kind this job reads (``mdi``: the MDI protocol's)."""
    config: BenchmarkConfig
    rounds: int
    """R: the DAgger rounds of the pairs."""
    bc: BCConfig
    dagger_bc: BCConfig
    early_stop: float | None
    mdi: MDIConfig | None
    """The run's MDI protocol (``bc`` resolved) when the job runs its methods."""
    priors: dict[str, HeadPrior] = field(default_factory=dict)
    """Each prior of the methods whose fits carry one, by its mean (a mapper kind or ``zero``)."""


Rows = dict[MethodKey, dict[str, Any]]
"""Rows by key, as a chain makes them."""


def benchmark_row(
    key: MethodKey, seed: int, traj: Trajectory, queries: int, labels: list[dict[str, Any]]
) -> dict[str, Any]:
    """A row of ``key`` on ``seed``: the outcome of ``traj``, its cumulative ``queries`` and its ledger ``labels``."""
    return {
        "method": key.method,
        "setting": key.setting,
        "demo_fraction": key.demo_fraction,
        "seed": seed,
        "success": bool(traj.success),
        "reward": float(traj.reward),
        "steps": int(traj.steps),
        "expert_queries": int(queries),
        **tally(labels),
        "labels": labels,
    }


def benchmark_seed(job: BenchmarkJob) -> dict[str, Any]:
    """Run the job's method keys on one seed; returns ``seed`` and ``entries`` (by key id).

    With ``config.lanes`` above 1 every chain of rollouts (each gate setting's rounds, DAgger's,
    each mapper's head, each refit, the MDI protocol's seed) steps in lockstep lanes
    (:mod:`metadagger.imitation.lanes`); the MDI seed runs beside the first demonstration share's
    chains.
    """
    seed, keys = job.seed, job.keys
    rows: Rows = {}
    shots = [key for key in keys if isinstance(key, ShotKey)]
    mdi = [partial(_mdi_rows, job, shots)] if job.mdi is not None and shots else []
    with ExitStack() as stack:
        learner = stack.enter_context(
            SeedLearner(job.task, job.pistar, seed, head_init_seed=job.bc.head_init_seed(seed))
        )
        lanes = None
        if job.config.lanes > 1:
            lanes = stack.enter_context(Lanes(job.task, learner.policy.net, width=job.config.lanes))
        fresh = learner.head()
        [demo] = run_steps(learner, [demonstration], lanes)
        held = None  # the expert's states held out of every fit (benchmark.held_out_every)
        if job.config.held_out_every:
            demo, held = held_out(demo, job.config.held_out_every)
        for fraction in sorted({key.demo_fraction for key in keys}, reverse=True):
            mine = [key for key in keys if key.demo_fraction == fraction and not isinstance(key, ShotKey)]
            if not mine:
                continue
            share = demonstration_share(demo, fraction)
            [start] = run_steps(learner, [partial(_start, job, fresh, share, held, mine)], lanes)
            for found in run_steps(learner, [*_chains(job, start, mine), *mdi], lanes):
                rows.update(found)
            mdi = []
        for found in run_steps(learner, mdi, lanes):  # a run of MDI rows alone
            rows.update(found)
    return {"seed": seed, "entries": {key.id: [rows[key]] for key in keys if key in rows}}


@dataclass(frozen=True)
class _Start:
    """Where every row of one demonstration share starts: w_BC and its rollout."""

    demo: Trajectory
    fresh: np.ndarray
    """The seed's fresh head, which w_BC was fitted from."""
    w_bc: np.ndarray
    first: Trajectory
    """w_BC's rollout under the pairs' early stop: the BC row, the context's rollout and DAgger's first round."""
    context: np.ndarray | None
    """The seed's context, where a mapper reads one."""
    held: Dataset | None = None
    """The expert's states held out of every fit, where ``benchmark.held_out_every`` asks for them."""

    @property
    def queries(self) -> int:
        """The demonstration's queries."""
        return len(self.demo.obs)

    def labels(self) -> list[dict[str, Any]]:
        """The ledger of a row that read the demonstration and nothing more."""
        return [demonstration_record(self.queries)]


def _start(
    job: BenchmarkJob,
    fresh: np.ndarray,
    demo: Trajectory,
    held: Dataset | None,
    keys: list[MethodKey],
    learner: SeedLearner,
) -> _Start:
    """w_BC fitted on ``demo`` from the learner's fresh head, rolled out; the context if a mapper needs it."""
    data = demo.to_dataset()
    learner.load(fresh)
    w_bc = bc_head(learner, data, seeded(job.bc, job.seed))
    first = learner.roll(w_bc, early_stop=job.early_stop)
    needs_context = any(
        cached_mapper(job.mappers[key.mapper_kind]).needs_context
        for key in keys
        if key.mapper_kind is not None and not isinstance(key, ShotKey)
    )
    context = seed_context(learner.cache, data, first.to_dataset()) if needs_context else None
    return _Start(demo, fresh, w_bc, first, context, held)


Chain = Callable[[SeedLearner], Rows]
"""A chain of rollouts that makes some rows: a step of :func:`~metadagger.metal_dagger.method.run_steps`."""


def _chains(job: BenchmarkJob, start: _Start, keys: list[MethodKey]) -> list[Chain]:
    """One chain per group of ``keys`` that one chain of rollouts makes (:attr:`MethodKey.chain`), in table order."""
    groups: dict[str, list[MethodKey]] = {}
    for key in keys:
        groups.setdefault(key.chain, []).append(key)
    return [partial(CHAINS[type(group[0])], job, start, group) for group in groups.values()]


def _bc_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    rows = {key: benchmark_row(key, job.seed, start.first, start.queries, start.labels()) for key in keys}
    if start.held is not None:
        for row in rows.values():
            row["expert_loss"] = expert_loss(learner, start.w_bc, start.held)
    return rows


def _mapper_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    [key] = keys
    head = map_head(cached_mapper(job.mappers[key.mapper_kind]), start.w_bc, start.context)
    rollout = learner.roll(head, early_stop=job.early_stop)
    if key.reads_demonstration:
        return {key: benchmark_row(key, job.seed, rollout, start.queries, start.labels())}
    return {key: benchmark_row(key, job.seed, rollout, 0, [])}


def _seed_prior(job: BenchmarkJob, start: _Start, mean: str) -> Prior:
    """The seed's prior toward ``mean``: its kind's head for w_BC (and context), or zero."""
    prior = job.priors[mean]
    mapper = None if mean == ZERO else cached_mapper(job.mappers[mean])
    context = None if start.context is None else torch.from_numpy(start.context)
    return prior.prior(mean_head(mapper, torch.from_numpy(start.w_bc), context))


def _start_with_prior(job: BenchmarkJob, start: _Start, mean: str, learner: SeedLearner) -> tuple[_Start, Prior]:
    """Where a method with a prior toward ``mean`` starts: BC's fit of the demonstration from the fresh
    head, the seed's prior added to its loss, in ``w_bc``, and its rollout; and that prior."""
    prior = _seed_prior(job, start, mean)
    learner.load(start.fresh)
    head = bc_head(learner, start.demo.to_dataset(), seeded(job.bc, job.seed), called="BC with a prior", prior=prior)
    return dataclasses.replace(start, w_bc=head, first=learner.roll(head, early_stop=job.early_stop)), prior


def _prior_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    [key] = keys
    assert isinstance(key, PriorKey)
    begun, _ = _start_with_prior(job, start, key.mean, learner)
    return {key: benchmark_row(key, job.seed, begun.first, start.queries, start.labels())}


def _prior_dagger_rows(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    # DAgger from BC with a prior, the same prior in every refit: every visited state labelled
    assert isinstance(keys[0], PriorKey)
    begun, prior = _start_with_prior(job, start, keys[0].mean, learner)
    return _round_rows(job, start, keys, _rounds(job, begun, learner, None, prior=prior))


def _rounds(
    job: BenchmarkJob,
    start: _Start,
    learner: SeedLearner,
    gate: Gate | None,
    *,
    prior: Prior | None = None,
    reference: np.ndarray | None = None,
) -> Iterator[Round]:
    return dagger_rounds(
        learner,
        start=start.w_bc,
        first_rollout=start.first,
        demo=start.demo,
        rounds=job.rounds,
        fit=seeded(job.dagger_bc, job.seed),
        gate=gate,
        early_stop=job.early_stop,
        prior=prior,
        reference=reference,
        origin=start.fresh,
    )


def _dagger_rows(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    """Plain DAgger's rows, each with the coverage gap of the states DAgger visited up to its round;
    then DART's (:class:`DartKey`), at the labels DAgger held after each round."""
    demo = learner.cache.features_of(start.demo.to_dataset())
    visited: list[torch.Tensor] = []
    budgets: list[int] = []
    losses: list[float] = []  # each round's head on the held-out expert states, where there are some

    def with_gap(rounds: Iterator[Round]) -> Iterator[Round]:
        for r in rounds:
            assert r.labelled is not None  # plain DAgger labels every visited state
            visited.append(learner.cache.features_of(r.labelled))
            budgets.append(r.queries)
            if start.held is not None:
                losses.append(expert_loss(learner, r.head, start.held))
            yield r

    dart = [key for key in keys if isinstance(key, DartKey)]
    rounds = [key for key in keys if isinstance(key, RoundKey)]
    rows = _round_rows(job, start, rounds, with_gap(_rounds(job, start, learner, None)))
    for key, row in rows.items():
        row["coverage_gap"] = coverage_gap(demo, torch.cat(visited[: key.round]))  # type: ignore[attr-defined]
        if losses:
            row["expert_loss"] = losses[key.round - 1]  # type: ignore[attr-defined]
    if dart:
        rows.update(_dart_rows(job, start, dart, budgets, learner))
    return rows


def _dart_rows(job: BenchmarkJob, start: _Start, keys: list[DartKey], budgets: list[int], learner: SeedLearner) -> Rows:
    """DART's row after each round that ``keys`` name, at DAgger's ``budgets``; each perturbed
    episode is a takeover of its own in the ledger, filed under the round whose budget it was driven for."""
    by_round = {key.round: key for key in keys}
    rows: Rows = {}
    fit = seeded(job.dagger_bc, job.seed)
    made = dart_rounds(
        learner,
        start=start.w_bc,
        demo=start.demo,
        budgets=budgets[: max(by_round)],
        scale=job.config.dart_noise,
        fit=fit,
        early_stop=job.early_stop,
        origin=start.fresh,
    )
    filed: list[int] = []  # the round each episode was first drawn on
    for r in made:
        filed += [r.index] * (len(r.episodes) - len(filed))
        if r.index in by_round:
            labels = start.labels() + [
                round_record(index, np.arange(steps), None) for index, steps in zip(filed, r.episodes)
            ]
            rows[by_round[r.index]] = benchmark_row(by_round[r.index], job.seed, r.rollout, r.queries, labels)
            if start.held is not None:
                rows[by_round[r.index]]["expert_loss"] = expert_loss(learner, r.head, start.held)
    return rows


def _round_rows(job: BenchmarkJob, start: _Start, keys: list[MethodKey], rounds: Iterator[Round]) -> Rows:
    """A row after each round that ``keys`` name (their ``round``), each with its ledger so far."""
    by_round = {key.round: key for key in keys}  # type: ignore[attr-defined]
    labels, rows = start.labels(), {}
    for r in rounds:
        labels = [*labels, round_record(r.index, r.asked, r.scores)]
        if r.index in by_round:
            rows[by_round[r.index]] = benchmark_row(by_round[r.index], job.seed, r.rollout, r.queries, labels)
    return rows


def _gate_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    [key] = keys
    gate = make_gate(key.gate, key.value, **job.config.options_of(key.method))
    return {key: _last_round_row(job, start, key, _rounds(job, start, learner, gate))}


def _prior_gate_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    # gated DAgger from BC with a prior, the same prior in every refit
    [key] = keys
    assert isinstance(key, PriorGateKey)
    begun, prior = _start_with_prior(job, start, key.mean, learner)
    gate = make_gate(key.gate, key.value, **job.config.options_of(GATED_PREFIX + key.gate))
    return {key: _last_round_row(job, begun, key, _rounds(job, begun, learner, gate, prior=prior))}


def _disagree_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    # DAgger from w_BC labelling where the kind's head for w_BC and the current head act apart
    [key] = keys
    assert isinstance(key, DisagreeKey)
    reference = map_head(cached_mapper(job.mappers[key.kind]), start.w_bc, start.context)
    rounds = _rounds(job, start, learner, DisagreementGate(key.value), reference=reference)
    return {key: _last_round_row(job, start, key, rounds)}


def _last_round_row(job: BenchmarkJob, start: _Start, key: MethodKey, rounds: Iterator[Round]) -> dict[str, Any]:
    """The row after the last of ``rounds``, with every round's ledger."""
    labels = start.labels()
    for last in rounds:
        # only the last round's rollout makes the row: the earlier ones are let go as they end
        labels.append(round_record(last.index, last.asked, last.scores))
    return benchmark_row(key, job.seed, last.rollout, last.queries, labels)


def _refit_row(job: BenchmarkJob, start: _Start, keys: list[MethodKey], learner: SeedLearner) -> Rows:
    # DAgger's refits (from w_BC or the fresh head, as DAgger's fit says) on the demonstration alone
    [key] = keys
    data = start.demo.to_dataset()
    learner.load(start.w_bc)
    for index in range(1, key.rounds + 1):
        learner.start_refit(job.dagger_bc, start.fresh)
        bc_head(learner, data, seeded(job.dagger_bc, job.seed), called=f"BC's refit {index}")
    row = benchmark_row(key, job.seed, learner.roll(early_stop=job.early_stop), len(data), start.labels())
    if start.held is not None:
        row["expert_loss"] = expert_loss(learner, learner.head(), start.held)
    return {key: row}


#: The chain that makes each kind of key's rows (MDI's rows come from its own protocol); a method of
#: your own adds its key type here (docs/benchmark.md, "Adding a method").
CHAINS: dict[type, Callable[[BenchmarkJob, _Start, list[MethodKey], SeedLearner], Rows]] = {
    BCKey: _bc_row,
    MapperKey: _mapper_row,
    PriorKey: _prior_row,
    PriorRoundKey: _prior_dagger_rows,
    RoundKey: _dagger_rows,
    DartKey: _dagger_rows,
    GateKey: _gate_row,
    PriorGateKey: _prior_gate_row,
    DisagreeKey: _disagree_row,
    RefitKey: _refit_row,
}


def _mdi_rows(job: BenchmarkJob, keys: list[ShotKey], learner: SeedLearner) -> Rows:
    """Table 6's one- and two-shot outcomes of DAgger-MDI, DAgger-BC and DAgger on this seed, by the
    MDI protocol's own learner of the seed (in ``learner``'s lane, where it has one)."""
    assert job.mdi is not None
    mdi_job = MDIJob(
        task=job.task,
        pistar=job.pistar,
        seed=job.seed,
        methods=tuple(MDI_METHODS),
        mappers={"dagger-mdi": job.mappers[MDI_MAPPER]},
        config=job.mdi,
        context_early_stop=job.early_stop,
    )
    outcomes = {method: rows[0] for method, rows in evaluate_mdi_seed(mdi_job)["entries"].items()}
    out: Rows = {}
    for key in keys:
        r = outcomes[key.method]
        two = key.shot == "twoshot" and r["two_shot_run"]
        labels = [demonstration_record(r["demo_steps"])]
        if two:  # the two-shot test's DAgger round labels every state of the one-shot head's rollout
            labels.append(round_record(1, np.arange(r["expert_queries"] - r["demo_steps"]), None))
        out[key] = {
            "method": key.method,
            "setting": key.setting,
            "demo_fraction": key.demo_fraction,
            "seed": job.seed,
            "success": r["two_shot_success"] if key.shot == "twoshot" else r["one_shot_success"],
            "reward": r["two_shot_reward"] if two else r["one_shot_reward"],
            "steps": r["two_shot_steps"] if two else r["one_shot_steps"],
            "expert_queries": r["expert_queries"] if key.shot == "twoshot" else r["demo_steps"],
            **tally(labels),
            "labels": labels,
        }
    return out
