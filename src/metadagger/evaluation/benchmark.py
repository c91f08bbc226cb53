"""Success against expert queries: DAgger, gated DAgger baselines and MetaL DAgger on one chart.

Every method starts where the pairs start: pi*'s frozen trunk and a head fitted by BC on the
seed's expert demonstration (w_BC). A *query* is one expert label of one state: each
demonstration step, and each visited state a DAgger round chooses to label; the part of the
action the environment's expert always drives (CarRacing's gas and brake, Fetch's gripper) is not
a query. Per seed, with rows ``(method, setting, seed)``:

- ``bc``: w_BC rolled out (the demonstration's queries only).
- ``mdm-<kind>``: each mapper kind and control applied to w_BC (MDM: no further query).
- ``dagger``: rounds 1..R of the pairs' DAgger (every visited state labelled), one row per round
  (setting = the round), with cumulative queries.
- ``dagger-random``, ``dagger-ensemble``, ``dagger-safe``, ``dagger-novelty``: the same R rounds,
  labelling only the states their gate (:mod:`metadagger.imitation.gates`) selects; one row per
  setting of the gate's grid (the random share p, or the score quantile), after round R.
- ``dagger-mdi``, ``dagger-bc-init``, ``dagger-xavier`` (runs with an ``mdi`` section): Table 6's
  one-shot and two-shot tests (settings ``one-shot``, ``two-shot``).

A row's outcome is one rollout of the policy after that many rounds (the rollout that also starts
the next round, which is deterministic, so nothing is rolled out twice).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.evaluation.mdi import MDIConfig, MDIJob, evaluate_mdi_seed
from metadagger.evaluation.rows import write_csv
from metadagger.imitation.bc import BCConfig, FeatureCache, fit_bc
from metadagger.imitation.data import Aggregate, Dataset
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.gates import GATES, Gate, Labelled, make_gate
from metadagger.imitation.metrics import summarize
from metadagger.imitation.rollouts import Trajectory, rollout
from metadagger.evaluation.tables import method_label
from metadagger.utils.io import write_json
from metadagger.runfolder.layout import RunLayout
from metadagger.mapping.mappers import cached_mapper
from metadagger.metal.context import seed_context
from metadagger.metal.groundtruth import cached_groundtruth, head_from_groundtruth
from metadagger.utils.plotting import plt, save_figure
from metadagger.policies import Policy
from metadagger.runfolder.driver import RowLog, SeedJob, Stamp, StageOptions, drive, plan
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task

#: Gated DAgger methods and the gate each one uses.
GATED = {f"dagger-{name}": name for name in GATES}
#: What the MDI protocol's methods are called in the benchmark (its ``dagger`` is a Xavier start).
MDI_NAMES = {"dagger-mdi": "dagger-mdi", "dagger-bc": "dagger-bc-init", "dagger": "dagger-xavier"}
#: Columns of ``benchmark/queries.csv``.
FIELDS = ("method", "setting", "seed", "success", "reward", "steps", "expert_queries")
MDM_PREFIX = "mdm-"


@dataclass(frozen=True)
class BenchmarkConfig:
    """Which methods the benchmark runs, on which unseen seeds, with which gate grids."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or the pairs)."""
    methods: tuple[str, ...] = ("bc", "mdm", "dagger", *GATED)
    """``bc``, ``mdm`` (every kind of ``evaluate.methods``), ``dagger``, the gated methods, and
    ``mdi`` (the MDI protocol's methods; runs with an ``mdi`` section)."""
    grids: dict = field(default_factory=lambda: {"dagger-random": [0.05, 0.2, 0.5], "dagger-ensemble": [0.5, 0.8, 0.95],
                                                "dagger-safe": [0.5, 0.8, 0.95], "dagger-novelty": [0.5, 0.8, 0.95]})
    """Each gated method's sweep: the random share p, or the score quantile above which a state is
    labelled (about 1 - quantile of each round's states). The defaults span label shares of about
    50%, 20% and 5%, fixed before any benchmark ran (not tuned on any seeds)."""
    ensemble_heads: int = 5
    """K, the ensemble gate's bootstrap heads."""
    novelty_k: int = 1
    """k, the novelty gate's neighbour."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("benchmark.seeds must not be empty")
        known = ("bc", "mdm", "dagger", *GATED, "mdi")
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
                    raise UserError(f"benchmark.grids.{method} is missing or empty; give its settings, e.g. [0.5, 0.8, 0.95]")
                for value in grid:
                    make_gate(GATED[method], value, **self.gate_options(method))  # range checks now, not hours later
        if self.ensemble_heads < 2 or self.novelty_k < 1:
            raise UserError(f"benchmark.ensemble_heads must be >= 2 and benchmark.novelty_k >= 1, got "
                            f"{self.ensemble_heads} and {self.novelty_k}")

    def gate_options(self, method: str) -> dict[str, Any]:
        """Keyword options of a gated method's gate."""
        return {"dagger-ensemble": {"K": self.ensemble_heads}, "dagger-novelty": {"k": self.novelty_k}}.get(method, {})


@dataclass(frozen=True)
class BenchmarkJob(SeedJob):
    """One seed's benchmark; its methods are keys ``method@setting`` (see :func:`method_keys`)."""

    mappers: dict[str, str]
    """Mapper file of every MDM kind this job runs."""
    config: BenchmarkConfig
    rounds: int
    """R: the DAgger rounds of the pairs."""
    bc: BCConfig
    dagger_bc: BCConfig
    early_stop: float | None
    mdi: MDIConfig | None
    """The run's MDI protocol (``bc`` resolved) when the job runs its methods."""


def method_keys(config: BenchmarkConfig, *, rounds: int, kinds: tuple[str, ...], mdi: bool) -> list[str]:
    """Every ``method@setting`` the benchmark rows of one seed are made of, in table order."""
    keys: list[str] = []
    for method in config.methods:
        if method == "bc":
            keys.append("bc@")
        elif method == "mdm":
            keys += [f"{MDM_PREFIX}{kind}@" for kind in kinds]
        elif method == "dagger":
            keys += [f"dagger@{r}" for r in range(1, rounds + 1)]
        elif method in GATED:
            keys += [f"{method}@{value:g}" for value in config.grids[method]]
        elif method == "mdi" and mdi:
            keys += [f"{name}@{shot}" for name in MDI_NAMES.values() for shot in ("one-shot", "two-shot")]
    return keys


def _row(key: str, seed: int, traj: Trajectory, queries: int) -> dict[str, Any]:
    method, setting = key.split("@")
    return {"method": method, "setting": setting, "seed": seed, "success": bool(traj.success), "reward": float(traj.reward),
            "steps": int(traj.steps), "expert_queries": int(queries)}


def benchmark_seed(job: BenchmarkJob) -> dict[str, Any]:
    """Run the job's ``method@setting`` keys on one seed; returns ``seed`` and ``entries``."""
    seed = job.seed
    pistar = cached_groundtruth(job.groundtruth)
    policy = head_from_groundtruth(pistar, job.bc.head_init_seed(seed))
    bc = dataclasses.replace(job.bc, seed=seed)
    dagger_bc = dataclasses.replace(job.dagger_bc, seed=seed)
    env = job.task.make_env()
    entries: dict[str, list[dict[str, Any]]] = {}
    wanted = set(job.methods)

    def run(head: np.ndarray) -> Trajectory:
        policy.load_head_vector(torch.from_numpy(head))
        stop = None if job.early_stop is None else CosineEarlyStop(threshold=job.early_stop)
        return rollout(env, seed=seed, policy=policy, early_stop=stop)

    try:
        demo = rollout(env, seed=seed, policy=None)
        data = demo.to_dataset()
        cache = FeatureCache(policy)
        fit_bc(policy, data, bc, cache=cache)
        w_bc = policy.head_vector().numpy().copy()
        first = run(w_bc)
        if "bc@" in wanted:
            entries["bc@"] = [_row("bc@", seed, first, len(data))]
        mdm = {key: cached_mapper(job.mappers[key.split("@")[0].removeprefix(MDM_PREFIX)])
               for key in job.methods if key.startswith(MDM_PREFIX)}
        # w_BC's rollout under the pairs' early stop is the one a context summarises
        context = seed_context(cache, data.obs, first.obs) if any(m.needs_context for m in mdm.values()) else None
        for key, mapper in mdm.items():
            entries[key] = [_row(key, seed, run(mapper(w_bc, context)), len(data))]
        if any(k.startswith("dagger@") for k in job.methods):
            for r, (traj, queries) in enumerate(_gated_rounds(policy, w_bc, first, demo, None, job, dagger_bc, cache, run), 1):
                if f"dagger@{r}" in wanted:
                    entries[f"dagger@{r}"] = [_row(f"dagger@{r}", seed, traj, queries)]
        for key in (k for k in job.methods if k.split("@")[0] in GATED):
            method, setting = key.split("@")
            gate = make_gate(GATED[method], float(setting), **job.config.gate_options(method))
            *_, (traj, queries) = _gated_rounds(policy, w_bc, first, demo, gate, job, dagger_bc, cache, run)
            entries[key] = [_row(key, seed, traj, queries)]
        if job.mdi is not None and any(k.split("@")[0] in MDI_NAMES.values() for k in job.methods):
            entries.update(_mdi_entries(job))
    finally:
        env.close()
    return {"seed": seed, "entries": entries}


def _gated_rounds(policy: Policy, w_bc: np.ndarray, first: Trajectory, demo: Trajectory, gate: Gate | None,
                  job: BenchmarkJob, dagger_bc: BCConfig, cache: FeatureCache,
                  run: Callable[[np.ndarray], Trajectory]) -> Iterator[tuple[Trajectory, int]]:
    """R DAgger rounds from w_BC, labelling what ``gate`` selects (every visited state if None);
    yields, after each round's refit, the rollout of the refitted policy and the cumulative queries.
    ``first`` is w_BC's own rollout, which round 1 labels."""
    generator = torch.Generator().manual_seed(job.seed)
    data = Aggregate([demo.to_dataset()])
    actions = demo.expert_labels  # on the demonstration the expert acted
    queries = len(data)
    policy.load_head_vector(torch.from_numpy(w_bc))
    traj = first
    for _ in range(job.rounds):
        if gate is None:
            keep = np.ones(traj.steps, dtype=bool)
        else:
            labelled = Labelled(features=cache.features_of(data), labels=_tensor(data.labels), learner_actions=_tensor(actions))
            keep = gate.select(cache.features(traj.obs), _tensor(traj.learner_actions), labelled, generator=generator).numpy()
        if keep.any():
            data = data.append(Dataset(obs=traj.obs[keep], labels=traj.expert_labels[keep]))
            actions = np.concatenate([actions, traj.learner_actions[keep]])
            queries += int(keep.sum())
            fit_bc(policy, data, dagger_bc, cache=cache)
        traj = run(policy.head_vector().numpy().copy())
        yield traj, queries


def _tensor(values: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(values))


def _mdi_entries(job: BenchmarkJob) -> dict[str, list[dict[str, Any]]]:
    """Table 6's one- and two-shot outcomes of DAgger-MDI, DAgger-BC and DAgger on this seed."""
    assert job.mdi is not None
    mdi_job = MDIJob(task=job.task, groundtruth=job.groundtruth, seed=job.seed, methods=tuple(MDI_NAMES),
                     mappers={"dagger-mdi": job.mappers["mdi"]}, config=job.mdi, context_early_stop=job.early_stop)
    out: dict[str, list[dict[str, Any]]] = {}
    for method, rows in evaluate_mdi_seed(mdi_job)["entries"].items():
        r = rows[0]
        name = MDI_NAMES[method]
        one = {"method": name, "setting": "one-shot", "seed": job.seed, "success": r["one_shot_success"],
               "reward": r["one_shot_reward"], "steps": r["one_shot_steps"], "expert_queries": r["demo_steps"]}
        two = {"method": name, "setting": "two-shot", "seed": job.seed, "success": r["two_shot_success"],
               "reward": r["two_shot_reward"] if r["two_shot_run"] else r["one_shot_reward"],
               "steps": r["two_shot_steps"] if r["two_shot_run"] else r["one_shot_steps"], "expert_queries": r["expert_queries"]}
        out[f"{name}@one-shot"], out[f"{name}@two-shot"] = [one], [two]
    return out


def benchmark_stamps(task: Task, layout: RunLayout, job_settings: dict[str, Any], config: BenchmarkConfig,
                     keys: list[str], mdi: MDIConfig | None, mdi_mapper: str | None) -> dict[str, Stamp]:
    """What each ``method@setting`` is made from: the shared fits, pi*, and the method's own inputs."""
    common = {"protocol": "benchmark", "task": task.name, **job_settings,
              "groundtruth_fingerprint": file_fingerprint(layout.groundtruth)}
    stamps: dict[str, Stamp] = {}
    for key in keys:
        method = key.split("@")[0]
        own: dict[str, Any] = {}
        if method.startswith(MDM_PREFIX):
            own = {"mapper_fingerprint": file_fingerprint(layout.mapper(method.removeprefix(MDM_PREFIX)))}
        elif method in GATED:
            own = {"gate": config.gate_options(method)}
        elif method in MDI_NAMES.values() and mdi is not None and mdi_mapper is not None:
            own = {"mdi": stamp_of(mdi, drop=("seeds", "controls")), "mapper_fingerprint": file_fingerprint(layout.mapper(mdi_mapper))}
        stamps[key] = {**common, **own}
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
    """Run the missing rows of the benchmark; write ``queries.csv``, ``summary.json`` and the figure.

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
        raise UserError(f"benchmark method mdi needs an mdi section, but run {layout.root} has none; "
                        "drop mdi from --methods (or benchmark.methods), or add an mdi section")
    keys = method_keys(config, rounds=rounds, kinds=kinds, mdi=with_mdi)
    settings = {"rounds": rounds, "bc": stamp_of(bc), "dagger_bc": stamp_of(dagger_bc), "early_stop": early_stop}
    stamps = benchmark_stamps(task, layout, settings, config, keys, mdi if with_mdi else None, mdi.mapper if with_mdi else None)
    log = RowLog(layout.benchmark_log)
    todo = plan(config.seeds, stamps, log, rebuild=options.rebuild, what="the benchmark",
                fix=f"run `metadagger benchmark --out {layout.root} --rebuild` to redo it, or `metadagger reproduce`")
    mappers = {kind: str(layout.mapper(kind)) for kind in kinds}
    if with_mdi:
        mappers["mdi"] = str(layout.mapper(mdi.mapper))
    jobs = [BenchmarkJob(task=task, groundtruth=str(layout.groundtruth), seed=p.seed, methods=p.methods, mappers=mappers,
                         config=config, rounds=rounds, bc=bc, dagger_bc=dagger_bc, early_stop=early_stop,
                         mdi=mdi if with_mdi else None) for p in todo]
    drive(benchmark_seed, jobs, log=log, stamps=stamps, options=options, desc="benchmark")
    rows = log.rows(config.seeds, stamps)
    write_csv(layout.benchmark_table, rows, fields=FIELDS)
    summary = summarize_benchmark(rows, meta_queries)
    write_json(layout.benchmark_summary, summary)
    plot_queries(summary, layout.benchmark_figure)
    return rows


def summarize_benchmark(rows: list[dict[str, Any]], meta_queries: dict[str, int]) -> dict[str, Any]:
    """Per (method, setting): success rate with its 95% Wilson interval, mean reward and mean
    queries per seed; and the queries spent on meta-training."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], str(r["setting"])), []).append(r)
    entries = []
    for (method, setting), group in groups.items():
        s = summarize(group)
        entries.append({"method": method, "setting": setting, "seeds": s["episodes"], "successes": s["successes"],
                        "success_rate": s["success_rate"], "success_ci_low": s["success_ci_low"],
                        "success_ci_high": s["success_ci_high"], "mean_reward": s["mean_reward"],
                        "mean_queries": s["expert_queries"] / s["episodes"]})
    return {"entries": entries, "meta_training_queries": dict(meta_queries)}


def plot_queries(summary: dict[str, Any], path: Path) -> Path:
    """Success (95% intervals) against mean expert queries per seed, one line per method, log x."""
    by_method: dict[str, list[dict[str, Any]]] = {}
    for e in summary["entries"]:
        by_method.setdefault(e["method"], []).append(e)
    fig, ax = plt.subplots(figsize=(7.5, 4.8), layout="constrained")
    for method, points in by_method.items():
        points = sorted(points, key=lambda e: e["mean_queries"])
        x = [max(e["mean_queries"], 1.0) for e in points]
        y = [e["success_rate"] for e in points]
        err = [[e["success_rate"] - e["success_ci_low"] for e in points], [e["success_ci_high"] - e["success_rate"] for e in points]]
        ax.errorbar(x, y, yerr=err, marker="o", ms=4, capsize=2, lw=1.2, label=method_label(method))
    ax.set_xscale("log")
    ax.set_xlabel("mean expert queries per seed (log)")
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize="small", ncol=2)
    return save_figure(fig, path)
