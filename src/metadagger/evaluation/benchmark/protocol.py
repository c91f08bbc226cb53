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
- ``dagger-<gate>`` for every gate (:mod:`metadagger.imitation.gate_registry`, plug-ins included):
  the same R rounds, labelling only the states the gate selects; one row per setting of the
  gate's grid, after round R. ``dagger-oracle`` is a reference, not a method: it labels exactly
  the states where the learner is wrong (``benchmark.oracle``).
- ``dagger-mdi``, ``dagger-bc-init``, ``dagger-xavier`` (runs with an ``mdi`` section): Table 6's
  one-shot and two-shot tests (settings ``one-shot``, ``two-shot``).

With ``demo_fractions`` below 1, BC, the learned MDM kinds and the gated settings run again from
the demonstration's first share of steps (:func:`~metadagger.metal_dagger.method.demonstration_share`),
so that the chart shows whether mapping can replace part of the demonstration.

A row's outcome is one rollout of the policy after that many rounds (the rollout that also starts
the next round, which is deterministic, so nothing is rolled out twice). Each row also keeps its
query ledger (:mod:`metadagger.evaluation.benchmark.ledger`). One seed's chains of rollouts are in
:mod:`metadagger.evaluation.benchmark.seed_chains`, the summary and its statistics in
:mod:`metadagger.evaluation.benchmark.summary`, the figure in :mod:`metadagger.evaluation.benchmark.figure`.
The methods that read a mapper (``prior``, ``prior-dagger``, ``prior-gated``, ``disagree``) are in
:mod:`metadagger.evaluation.benchmark.methods` and docs/benchmark.md.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import torch

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.coverage_figure import has_twins, plot_coverage
from metadagger.evaluation.benchmark.figure import plot_queries
from metadagger.evaluation.benchmark.ledger import ledger_lines
from metadagger.evaluation.benchmark.methods import (
    MDI_MAPPER,
    PRIOR_METHODS,
    MethodKey,
    StampInputs,
    benchmark_methods,
    with_demo_fractions,
)
from metadagger.evaluation.benchmark.seed_chains import BenchmarkJob, benchmark_seed
from metadagger.evaluation.benchmark.summary import summarize_benchmark
from metadagger.evaluation.mdi import MDIConfig
from metadagger.evaluation.rows import write_csv
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.lanes import lanes_stamp
from metadagger.mapping.mappers import MapperFile
from metadagger.mapping.priors import HeadPrior
from metadagger.runfolder.driver import RowLog, StageOptions, Stamp, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import write_json
from metadagger.utils.jsonl import write_lines
from metadagger.utils.kernels import kernel_stamp
from metadagger.utils.plotting import draw_figure

#: Columns of ``benchmark/queries.csv`` (docs/benchmark.md); the query ledger's two are the last.
FIELDS = (
    "method",
    "setting",
    "demo_fraction",
    "seed",
    "success",
    "reward",
    "steps",
    "expert_queries",
    "takeovers",
    "episodes_asked",
)
#: The version of what a row records beyond its outcome (in every row's stamp): rows from before
#: the query ledger are made again.
ROW_RECORD = "ledger-1"


def method_keys(config: BenchmarkConfig, *, rounds: int, kinds: tuple[str, ...], mdi: bool) -> list[MethodKey]:
    """Every method key the benchmark rows of one seed are made of, in table order (the oracle last)."""
    methods = benchmark_methods()
    grids = {method: config.grid(method) for method in config.gated()}
    names = [*(m for m in config.methods if m != "mdi"), *(m for m in config.gated() if m not in config.methods)]
    names += ["mdi"] if "mdi" in config.methods else []
    keys = [key for name in names for key in methods[name].keys(rounds, kinds, grids, mdi)]
    return with_demo_fractions(keys, config.demo_fractions)


def benchmark_stamps(
    task: Task,
    layout: RunLayout,
    job_settings: dict[str, Any],
    config: BenchmarkConfig,
    keys: list[MethodKey],
    mdi: MDIConfig | None,
    mdi_mapper: str | None,
    priors: dict[str, HeadPrior] | None = None,
) -> dict[str, Stamp]:
    """What each method key's rows are made from: the shared fits, pi*, and the method's own inputs."""
    common = {
        "protocol": "benchmark",
        "rows": ROW_RECORD,
        **kernel_stamp(),
        **task_stamp(task),
        **job_settings,
        "pistar_fingerprint": file_fingerprint(layout.pistar),
        # every row of a seed starts from its demonstration less the held-out steps
        **({"held_out_every": config.held_out_every} if config.held_out_every else {}),
    }
    stamps: dict[str, Stamp] = {}
    inputs = StampInputs(
        config.options_of,
        None if mdi is None else stamp_of(mdi, drop=("seeds", "controls")),
        {mean: prior_stamp(prior) for mean, prior in (priors or {}).items()},
        config.dart_noise,
    )
    for key in keys:
        own = key.own_stamp(inputs)
        if key.mapper_kind is not None:
            own["mapper_fingerprint"] = file_fingerprint(_mapper_path(layout, key.mapper_kind, mdi_mapper))
        stamps[key.id] = {**common, **own}
    return stamps


def prior_stamp(prior: HeadPrior) -> dict[str, Any]:
    """What a prior's rows are made from beyond its mean's mapper: its strength and precision."""
    precision = prior.precision.to(torch.float32).contiguous().numpy()
    return {"strength": prior.setting, "precision_sha256": hashlib.sha256(precision.tobytes()).hexdigest()}


def _mapper_path(layout: RunLayout, kind: str, mdi_mapper: str | None) -> Path:
    """The mapper file a key reads: its kind's, or the MDI protocol's for :data:`MDI_MAPPER`."""
    return layout.mapper(mdi_mapper if kind == MDI_MAPPER and mdi_mapper is not None else kind)


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
    priors: dict[str, HeadPrior] | None = None,
    options: StageOptions = StageOptions(),
    desc: str = "benchmark",
) -> list[dict[str, Any]]:
    """Run the missing rows of the benchmark; write ``queries.csv``, the query ledger
    ``labels.jsonl``, ``summary.json``, then the figure (a figure that fails is a warning: the rows
    and the summary are on disk before it).

    Args:
        task: the task.
        layout: the run folder (pi* and mappers are read from it; results go to ``benchmark/``).
        config: seeds, methods and gate grids.
        rounds: R, the pairs' DAgger rounds; ``bc``, ``dagger_bc``, ``early_stop``: the pairs' fits
            and early stop, so every method starts where the pairs start.
        kinds: the mapper kinds MDM runs with, and the means of the priors (with ``zero``).
        mdi: the run's MDI protocol (``bc`` resolved), or None.
        meta_queries: expert queries spent on meta-training (``pistar``, ``pairs``), for the report.
        priors: the ``prior`` method's priors by mean (:mod:`metadagger.mapping.priors`; the
            stage builds them from the pairs), where ``config.methods`` has it.
        options: rebuild (redo rows made from other inputs; else they are an error), executor,
            workers, progress: as for every stage.
        desc: the name its progress lines carry (which set of seeds this is).

    Raises:
        UserError: ``config.methods`` has ``mdi`` but the run has no MDI protocol, or ``prior``
            without its priors; or, without ``rebuild``, rows made from other inputs.
    """
    with_mdi = "mdi" in config.methods
    if with_mdi and mdi is None:
        raise UserError(
            f"benchmark method mdi needs an mdi section, but run {layout.root} has none; "
            "drop mdi from --methods (or benchmark.methods), or add an mdi section"
        )
    keys = method_keys(config, rounds=rounds, kinds=kinds, mdi=with_mdi)
    missing = sorted({key.prior_mean for key in keys if key.prior_mean is not None} - set(priors or {}))
    if missing:
        raise UserError(
            f"benchmark methods {', '.join(PRIOR_METHODS)} need the priors toward {missing}; build them from the pairs"
        )
    settings = {"rounds": rounds, "bc": stamp_of(bc), "dagger_bc": stamp_of(dagger_bc), "early_stop": early_stop}
    settings.update(lanes_stamp(config.lanes))  # stamped unless 1: rows made alone stay current
    mdi_mapper = mdi.mapper if with_mdi and mdi is not None else None
    stamps = benchmark_stamps(task, layout, settings, config, keys, mdi if with_mdi else None, mdi_mapper, priors)
    log = RowLog(layout.benchmark_log)
    todo = plan(
        config.seeds,
        stamps,
        log,
        rebuild=options.rebuild,
        called="the benchmark",
        fix=f"run `metadagger benchmark --out {layout.root} --rebuild` to redo it, or `metadagger reproduce`",
    )
    # each mapper file as its stamps fingerprinted it: a worker refuses other bytes
    mappers = {
        key.mapper_kind: MapperFile(
            str(_mapper_path(layout, key.mapper_kind, mdi_mapper)), stamps[key.id]["mapper_fingerprint"]
        )
        for key in keys
        if key.mapper_kind is not None
    }
    by_id = {key.id: key for key in keys}
    jobs = [
        BenchmarkJob(
            task=task,
            pistar=str(layout.pistar),
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
            priors=dict(priors or {}),
        )
        for p in todo
    ]
    drive(benchmark_seed, jobs, log=log, stamps=stamps, options=options, desc=desc)
    rows = log.rows(config.seeds, stamps)
    write_csv(layout.benchmark_table, rows, fields=FIELDS)
    write_lines(layout.benchmark_labels, ledger_lines(rows))
    summary = summarize_benchmark(rows, meta_queries)
    write_json(layout.benchmark_summary, summary)
    draw_figure(layout.benchmark_figure, lambda path: plot_queries(summary, path))
    if has_twins(summary["coverage"]):
        draw_figure(layout.benchmark_coverage_figure, lambda path: plot_coverage(summary["coverage"], path))
    return rows
