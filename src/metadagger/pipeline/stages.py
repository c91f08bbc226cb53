"""The MetaL DAgger pipeline as stages over one run folder:
pistar -> pairs -> mappers -> evaluate (MDM) -> mdi -> benchmark -> report; diagnose and tune
run on their own, as do export and video (:mod:`metadagger.pipeline.outputs`).

Each stage reads the run's config and declares, in one call, the previous stages' artifacts it
reads (:func:`~metadagger.pipeline.stage_inputs.stage_inputs`: pi*, the pairs, some mappers),
which are checked complete and made from today's config; it skips the work whose artifacts exist.
Run alone, a stage whose inputs changed refuses with one line naming what changed; with
``rebuild`` (what ``reproduce`` passes) it redoes the stale work instead, so a changed input
rebuilds exactly what depends on it. The mdi stage runs only for runs whose config has an ``mdi``
section (Fetch). With ``log: tensorboard`` each stage then rewrites its TensorBoard scalars from
its artifacts (:mod:`metadagger.evaluation.tensorboard`).

The entry points a Python program starts with (:func:`reproduce`, :func:`init_run`,
:func:`load_run`) pin the CPU kernels first, as the command line does
(:mod:`metadagger.utils.kernels`).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from pathlib import Path
from typing import Callable, Mapping, Sequence

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.methods import PRIOR_METHODS
from metadagger.evaluation.benchmark.protocol import run_benchmark
from metadagger.evaluation.curves import plot_curves
from metadagger.evaluation.diagnose import diagnose_mappers
from metadagger.evaluation.mdi import evaluate_mdi
from metadagger.evaluation.mdm import evaluate_run
from metadagger.evaluation.report.build import build_report
from metadagger.evaluation.tensorboard import (
    Scalar,
    benchmark_scalars,
    mapper_scalars,
    pairs_scalars,
    pistar_scalars,
    table_scalars,
    write_tensorboard,
)
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.gate_registry import check_gates_serve
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.priors import ZERO, HeadPrior, chosen_priors
from metadagger.mapping.registry import get_kind
from metadagger.mapping.search_space import check_tunable
from metadagger.mapping.train import MapperJob, train_mappers
from metadagger.mapping.tune import TuneResult, tune_mapper
from metadagger.metal_dagger.pairs import collect_pairs, negligible_change_warning
from metadagger.metal_dagger.pistar import (
    check_pistar,
    pistar_rates,
    train_pistar,
)
from metadagger.metal_dagger.store import PairStore
from metadagger.pipeline.run_config import RunConfig, init_run, load_run, save_run
from metadagger.pipeline.stage_inputs import StageInputs, run_task, stage_inputs
from metadagger.pipeline.stage_runs import records_config
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import run_lock
from metadagger.runfolder.stamps import file_fingerprint
from metadagger.tasks.identity import task_stamp
from metadagger.utils.executors import default_workers
from metadagger.utils.io import read_json
from metadagger.utils.kernels import kernel_stamp, pin_cpu_kernels
from metadagger.utils.plotting import draw_figure
from metadagger.utils.progress import note

STAGES = ("pistar", "pairs", "mappers", "evaluate", "mdi", "benchmark", "diagnose", "report")


def _log(layout: RunLayout, config: RunConfig, runs: Callable[[], Mapping[str, list[Scalar]]]) -> None:
    """With ``log: tensorboard``, replace the TensorBoard namespaces of ``runs()`` (namespace ->
    scalars, read from the stage's artifacts) under ``RUN/tb/``."""
    if config.log == "tensorboard":
        write_tensorboard(layout, runs())


@records_config
def stage_pistar(layout: RunLayout, config: RunConfig, options: StageOptions = StageOptions()) -> dict:
    """Train pi* (skipped when done and made from this config)."""
    # pi*'s rollouts use this machine's cores (a local pool) whatever executor the per-seed stages use
    workers = options.workers if options.executor == "local" and options.workers else default_workers()
    metrics = train_pistar(
        run_task(config, checked=True),  # pi* reads no earlier stage
        config.pistar,
        layout,
        rebuild=options.rebuild,
        progress=options.progress,
        workers=workers,
    )
    _log(layout, config, lambda: {"pistar": pistar_scalars(layout)})
    return metrics


@records_config
def stage_pairs(layout: RunLayout, config: RunConfig, options: StageOptions = StageOptions()) -> dict:
    """Collect the pairs of every seed not stored yet (with ``options.rebuild``, also the stale ones);
    refuses before any pair when pi* is below ``pistar.min_success`` on its unseen seeds."""
    inputs = stage_inputs(layout, config, checked=True)
    check_pistar(read_json(layout.pistar_metrics, "pi*'s metrics"), config.pistar, layout)
    summary = collect_pairs(inputs.task, layout, config.pairs, options)
    _log(layout, config, lambda: {"pairs": pairs_scalars(layout, config.pairs.seeds)})
    return summary


@records_config
def stage_mappers(
    layout: RunLayout, config: RunConfig, kinds: Sequence[str] | None = None, options: StageOptions = StageOptions()
) -> list[Path]:
    """Train the mappers of ``kinds`` (default: the kinds the run uses, ``config.mapper_kinds``)
    on the run's current kept pairs; curves.png beside each."""
    kinds = config.mapper_kinds if kinds is None else tuple(kinds)
    for kind in kinds:
        get_kind(kind)  # unknown kinds fail before any work
    inputs = stage_inputs(layout, config, pairs=True)
    head = inputs.pistar.head_vector()
    jobs = [
        MapperJob(
            split=inputs.split, config=config.mapper_config(kind), out_dir=layout.mapper_dir(kind), pistar_head=head
        )
        for kind in kinds
    ]
    train_mappers(jobs, rebuild=options.rebuild, options=options)
    for kind in kinds:
        draw_figure(
            layout.mapper_curves_figure(kind), lambda path, kind=kind: plot_curves(layout.mapper_curves(kind), path)
        )
    _log(layout, config, lambda: {f"mapper/{kind}": mapper_scalars(layout, kind) for kind in kinds})
    return [layout.mapper(kind) for kind in kinds]


@records_config
def stage_tune(
    layout: RunLayout,
    config: RunConfig,
    kind: str,
    *,
    trials: int,
    seed: int = 0,
    apply: bool = False,
    options: StageOptions = StageOptions(),
) -> TuneResult:
    """Search mapper ``kind``'s hyperparameters (:mod:`metadagger.mapping.tune`): trials train on
    the run's training pairs and are scored on its validation pairs, never on evaluation seeds.
    The study resumes from ``tune/<kind>.db`` (``options.rebuild`` starts a new one); ``apply``
    writes the best settings into the run's ``mappers`` section, for train-mapper and reproduce."""
    check_tunable(kind)  # before any work
    inputs = stage_inputs(layout, config, pairs=True)
    result = tune_mapper(
        inputs.split,
        config.mapper_config(kind),
        study=layout.tune_study(kind),
        summary=layout.tune_summary(kind),
        trials=trials,
        seed=seed,
        base_overrides=config.mappers.get(kind) or {},
        options=options,
    )
    if apply:
        save_run(layout.root, load_run(layout.root, [result.set_item]))  # validated like any --set
    return result


def _unseen(config: RunConfig, seeds: Sequence[int]) -> tuple[int, ...]:
    """``seeds`` as a tuple, checked to be none of pi*'s or the pairs' seeds."""
    used = config.seen_seeds
    seen = sorted(set(seeds) & used)
    if seen:
        raise UserError(f"evaluation seeds must be unseen, but {seen[:5]} were used for pi* or pairs; pick other seeds")
    return tuple(seeds)


@records_config
def stage_evaluate(
    layout: RunLayout, config: RunConfig, *, seeds: Sequence[int] | None = None, options: StageOptions = StageOptions()
) -> list[dict]:
    """MDM and one-shot evaluation on the config's unseen seeds (or on ``seeds``): the missing
    (seed, method) rows only."""
    eval_config = (
        config.evaluate if seeds is None else dataclasses.replace(config.evaluate, seeds=_unseen(config, seeds))
    )
    inputs = stage_inputs(layout, config, mappers=eval_config.methods)
    rows = evaluate_run(
        inputs.task, layout, eval_config, bc=config.pairs.bc, early_stop=config.pairs.early_stop, options=options
    )
    tables = ("mdm", "oneshot") if eval_config.oneshot else ("mdm",)
    _log(layout, config, lambda: {f"eval/{table}": table_scalars(layout.eval_table(table)) for table in tables})
    return rows


@records_config
def stage_mdi(
    layout: RunLayout, config: RunConfig, *, seeds: Sequence[int] | None = None, options: StageOptions = StageOptions()
) -> list[dict]:
    """The MDI protocol (DAgger-MDI vs DAgger-BC vs DAgger) on the config's unseen seeds (or on
    ``seeds``); [] for a run without an ``mdi`` section."""
    mdi = config.mdi_config
    if mdi is None:
        return []
    mdi = mdi if seeds is None else dataclasses.replace(mdi, seeds=_unseen(config, seeds))
    inputs = stage_inputs(layout, config, mappers=tuple(mdi.kinds.values()))
    rows = evaluate_mdi(inputs.task, layout, mdi, options, context_early_stop=config.pairs.early_stop)
    _log(layout, config, lambda: {"eval/mdi": table_scalars(layout.eval_table("mdi"))})
    return rows


@records_config
def stage_benchmark(
    layout: RunLayout,
    config: RunConfig,
    *,
    seeds: Sequence[int] | None = None,
    methods: Sequence[str] | None = None,
    options: StageOptions = StageOptions(),
) -> list[dict]:
    """Success against expert queries on the config's unseen seeds (or ``seeds``), for its methods
    (or ``methods``); [] for a run without a ``benchmark`` section."""
    bench = config.benchmark
    if bench is None:
        return []
    changes = {"seeds": _unseen(config, seeds)} if seeds is not None else {}
    if methods is not None:
        changes["methods"] = tuple(methods)
    bench = dataclasses.replace(bench, **changes) if changes else bench
    kinds = config.evaluate.methods if {"mdm", *PRIOR_METHODS, "disagree"} & set(bench.methods) else ()
    mdi = config.mdi_config if "mdi" in bench.methods else None
    with_priors = bool(set(PRIOR_METHODS) & set(bench.methods))
    inputs = stage_inputs(layout, config, pairs=with_priors, mappers=tuple(kinds) + ((mdi.mapper,) if mdi else ()))
    check_gates_serve(bench.gated(), discrete=inputs.task.is_discrete, task=config.task)
    priors = _benchmark_priors(layout, inputs, tuple(kinds), config.pairs.bc, options) if with_priors else None
    run = functools.partial(
        run_benchmark,
        inputs.task,
        rounds=config.pairs.dagger_rounds,
        bc=config.pairs.bc,
        dagger_bc=config.pairs.dagger_bc,
        early_stop=config.pairs.early_stop,
        kinds=tuple(kinds),
        mdi=mdi,
        meta_queries=_meta_training_queries(layout, config),
        priors=priors,
        options=options,
    )
    confirm = bench.confirm_seeds if seeds is None else ()
    if confirm:
        note(
            f"benchmark: the unseen seeds ({len(bench.seeds)}), then the confirmation seeds ({len(confirm)})",
            enabled=options.progress,
        )
    rows = run(layout, bench)
    if confirm:
        # the second set: the same methods on seeds fixed before any result was read
        second = dataclasses.replace(bench, seeds=confirm, confirm_seeds=())
        run(layout.confirmation(), second, desc="benchmark, confirmation seeds")
    _log(layout, config, lambda: {"benchmark": benchmark_scalars(layout)})
    return rows


def _benchmark_priors(
    layout: RunLayout, inputs: StageInputs, kinds: tuple[str, ...], bc: BCConfig, options: StageOptions
) -> dict[str, HeadPrior]:
    """The priors of the methods whose fits carry one (``PRIOR_METHODS``), toward each of ``kinds``'
    heads and zero: precision from the training pairs, strength chosen on the validation pairs
    (mapping/priors.py)."""
    stamp = {
        **kernel_stamp(),
        **task_stamp(inputs.task),
        "pistar": file_fingerprint(layout.pistar),
        "mappers": {kind: file_fingerprint(layout.mapper(kind)) for kind in kinds},
    }
    return chosen_priors(
        {kind: load_mapper(layout.mapper(kind)) for kind in kinds} | {ZERO: None},
        inputs.task,
        str(layout.pistar),
        inputs.split,
        bc,
        record=layout.benchmark_priors,
        inputs=stamp,
        progress=options.progress,
    )


@records_config
def stage_diagnose(layout: RunLayout, config: RunConfig, *, options: StageOptions = StageOptions()) -> dict:
    """The mapping diagnostics of every kind and control of ``evaluate.methods`` on the run's
    validation pairs (:mod:`metadagger.evaluation.diagnose`)."""
    kinds = tuple(config.evaluate.methods)
    inputs = stage_inputs(layout, config, pairs=True, mappers=kinds)
    learned = {kind: config.mapper_config(kind) for kind in kinds if get_kind(kind).learned}
    return diagnose_mappers(
        inputs.task,
        layout,
        inputs.split,
        {kind: load_mapper(layout.mapper(kind)) for kind in kinds},
        config.pairs,
        config.diagnose,
        scaling_configs=learned,
        split_seed=config.split_seed,
        outputs=inputs.pistar.net.head.out_features,
        discrete=inputs.pistar.discrete,
        options=options,
    )


def _meta_training_queries(layout: RunLayout, config: RunConfig) -> dict[str, int]:
    """Expert queries spent on pi* and on the pairs of ``pairs.seeds`` (each pair's demonstration
    and DAgger rounds)."""
    metrics = read_json(layout.pistar_metrics, "pi*'s metrics") if layout.pistar_metrics.is_file() else {}
    seeds = set(config.pairs.seeds)
    records = PairStore(layout.pairs_dir).records() if layout.pairs_dir.is_dir() else []
    return {
        "pistar": int(metrics.get("expert_queries", 0)),
        "pairs": sum(int(r["da"]["expert_queries"]) for r in records if r["seed"] in seeds),
    }


def _heading(number: int, stage: str, progress: bool) -> None:
    if progress:
        print(f"[{number}/{len(STAGES)}] {stage}", file=sys.stderr, flush=True)


def reproduce(
    task: str,
    preset: str,
    run: str | Path,
    *,
    presets_file: str | Path | None = None,
    overrides: Sequence[str] = (),
    diagnose: bool = False,
    device: str | None = None,
    options: StageOptions = StageOptions(),
) -> Path:
    """Every stage in order, each resuming where a previous run stopped and rebuilding what a
    changed input made stale (``options.rebuild`` is always on); returns the report path.
    ``presets_file``: a YAML file of presets to take ``preset`` from instead of the packaged one;
    ``overrides``: ``section.key=value`` items; ``diagnose``: also the mapping diagnostics on the
    validation pairs (:func:`stage_diagnose`), after the benchmark; ``device``: a ``--device`` value
    for a new run (:func:`init_run`). Pins the CPU kernels first
    (:func:`~metadagger.utils.kernels.pin_cpu_kernels`), as the command line does."""
    pin_cpu_kernels()
    config = init_run(run, task, preset, presets_file, overrides, device)
    with run_lock(run):  # the whole run: no other writer between two stages
        return _reproduce(RunLayout(run), config, options, diagnose=diagnose)


def _reproduce(layout: RunLayout, config: RunConfig, options: StageOptions, *, diagnose: bool) -> Path:
    options = dataclasses.replace(options, rebuild=True)
    stages = [
        ("pistar: pi*", lambda: stage_pistar(layout, config, options)),
        ("pairs (w_BC, w_DA)", lambda: stage_pairs(layout, config, options)),
        (f"mappers: {', '.join(config.mapper_kinds)}", lambda: stage_mappers(layout, config, options=options)),
        ("evaluate: MDM and one-shot", lambda: stage_evaluate(layout, config, options=options)),
        (
            "mdi: DAgger-MDI vs DAgger-BC vs DAgger" if config.mdi else "mdi: not in this preset",
            lambda: stage_mdi(layout, config, options=options),
        ),
        (
            "benchmark: success against expert queries" if config.benchmark else "benchmark: not in this preset",
            lambda: stage_benchmark(layout, config, options=options),
        ),
        (
            "diagnose: does a mapper learn anything?" if diagnose else "diagnose: not asked for (--diagnose)",
            lambda: stage_diagnose(layout, config, options=options) if diagnose else None,
        ),
    ]
    for number, (heading, stage) in enumerate(stages, 1):
        _heading(number, heading, options.progress)
        result = stage()
        if number == 1 and options.progress:
            print(f"pi*: {pistar_rates(result)}", file=sys.stderr, flush=True)
        warning = negligible_change_warning(result) if number == 2 else None
        if warning:
            print(warning, file=sys.stderr, flush=True)
    _heading(len(STAGES), "report", options.progress)
    return build_report(layout)


__all__ = [
    "STAGES",
    "init_run",
    "load_run",
    "reproduce",
    "stage_benchmark",
    "stage_diagnose",
    "stage_evaluate",
    "stage_pistar",
    "stage_mappers",
    "stage_mdi",
    "stage_pairs",
    "stage_tune",
    "StageOptions",
]
