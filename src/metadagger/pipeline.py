"""The MetaL DAgger pipeline as stages over one run folder:
groundtruth -> pairs -> mappers -> evaluate (MDM) -> mdi -> report. Each stage reads the run's
config and the previous stages' artifacts and skips the work whose artifacts exist, so
``reproduce`` resumes. The mdi stage runs only for runs whose config has an ``mdi`` section (Fetch).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence

from metadagger.errors import UserError
from metadagger.evaluation.curves import plot_curves
from metadagger.evaluation.mdi import evaluate_mdi
from metadagger.evaluation.mdm import MAPPER_METHODS, evaluate_run, mapper_path
from metadagger.evaluation.report import build_report
from metadagger.mapping.train import train_mapper
from metadagger.metal.groundtruth import groundtruth_path, load_groundtruth, train_groundtruth
from metadagger.metal.pairs import collect_pairs
from metadagger.metal.store import PairStore
from metadagger.policies import load_policy
from metadagger.run import RunConfig, init_run, load_run
from metadagger.tasks import make_task
from metadagger.tasks.base import Task


def run_task(config: RunConfig) -> Task:
    """The task a run was configured with."""
    return make_task(config.task, **config.task_kwargs)


def stage_groundtruth(run: Path, config: RunConfig, *, progress: bool = True) -> dict:
    """Train pi* (skipped when done)."""
    return train_groundtruth(run_task(config), config.groundtruth, run, progress=progress)


def stage_pairs(run: Path, config: RunConfig, *, executor: str = "local", workers: int | None = None,
                address: str | None = None, progress: bool = True) -> dict:
    """Collect the pairs of every seed not stored yet."""
    load_groundtruth(run)  # a missing or corrupt pi* is an error even when no seed is left
    return collect_pairs(run_task(config), groundtruth_path(run), config.pairs, run,
                         executor=executor, workers=workers, address=address, progress=progress)


def stage_mappers(run: Path, config: RunConfig, kinds: Sequence[str] | None = None, *, progress: bool = True) -> list[Path]:
    """Train the mappers of ``kinds`` (dm, sam, tam and the controls mean-da, pistar-head); by
    default the kinds the run evaluates (``config.mapper_kinds``)."""
    kinds = config.mapper_kinds if kinds is None else kinds
    unknown = sorted(set(kinds) - set(MAPPER_METHODS))
    if unknown:
        raise UserError(f"unknown mapper kind(s) {unknown}; expected {', '.join(MAPPER_METHODS)} or all")
    split = PairStore(run / "pairs").load_split(val_fraction=config.pairs.val_fraction, seed=config.split_seed, kept_only=True)
    if len(split.train_seeds) < 2:
        raise UserError(
            f"only {len(split.train_seeds) + len(split.val_seeds)} kept pairs in {run / 'pairs'}; "
            "collect more seeds (pairs.seeds) or relax pairs.keep"
        )
    head = load_policy(groundtruth_path(run)).head_vector()
    paths = []
    for kind in kinds:
        folder = mapper_path(run, kind).parent
        train_mapper(split, config.mapper_config(kind), folder, pistar_head=head, progress=progress)
        plot_curves(folder / "curves.csv", folder / "curves.png")
        paths.append(mapper_path(run, kind))
    return paths


def _unseen(config: RunConfig, seeds: Sequence[int]) -> tuple[int, ...]:
    """``seeds`` as a tuple, checked to be none of pi*'s or the pairs' seeds."""
    used = set(config.groundtruth.seeds) | set(config.groundtruth.eval_seeds) | set(config.pairs.seeds)
    seen = sorted(set(seeds) & used)
    if seen:
        raise UserError(f"evaluation seeds must be unseen, but {seen[:5]} were used for pi* or pairs; pick other seeds")
    return tuple(seeds)


def stage_evaluate(run: Path, config: RunConfig, *, seeds: Sequence[int] | None = None, executor: str = "local",
                   workers: int | None = None, address: str | None = None, progress: bool = True) -> list[dict]:
    """MDM and one-shot evaluation on the config's unseen seeds (or on ``seeds``)."""
    load_groundtruth(run)  # a missing or corrupt pi* is an error even when no seed is left
    eval_config = config.evaluate if seeds is None else dataclasses.replace(config.evaluate, seeds=_unseen(config, seeds))
    return evaluate_run(run_task(config), run, eval_config, groundtruth=groundtruth_path(run), bc=config.pairs.bc,
                        executor=executor, workers=workers, address=address, progress=progress)


def stage_mdi(run: Path, config: RunConfig, *, seeds: Sequence[int] | None = None, executor: str = "local",
              workers: int | None = None, address: str | None = None, progress: bool = True) -> list[dict]:
    """The MDI protocol (DAgger-MDI vs DAgger-BC vs DAgger) on the config's unseen seeds (or on
    ``seeds``); [] for a run without an ``mdi`` section."""
    if config.mdi is None:
        return []
    mdi_config = config.mdi if seeds is None else dataclasses.replace(config.mdi, seeds=_unseen(config, seeds))
    return evaluate_mdi(run_task(config), run, mdi_config, groundtruth=groundtruth_path(run),
                        mapper_path=mapper_path(run, mdi_config.mapper),
                        control_paths={kind: mapper_path(run, kind) for kind in mdi_config.controls},
                        executor=executor, workers=workers, address=address, progress=progress)


def reproduce(task: str, preset: str, run: str | Path, *, presets_file: str | Path | None = None, executor: str = "local",
              workers: int | None = None, address: str | None = None, progress: bool = True) -> Path:
    """Every stage in order, each resuming where a previous run stopped; returns the report path.
    ``presets_file``: a YAML file of presets to take ``preset`` from instead of the packaged one."""
    run = Path(run)
    config = init_run(run, task, preset, presets_file)
    stage_groundtruth(run, config, progress=progress)
    stage_pairs(run, config, executor=executor, workers=workers, address=address, progress=progress)
    stage_mappers(run, config, progress=progress)
    stage_evaluate(run, config, executor=executor, workers=workers, address=address, progress=progress)
    stage_mdi(run, config, executor=executor, workers=workers, address=address, progress=progress)
    return build_report(run)


__all__ = ["load_run", "reproduce", "run_task", "stage_evaluate", "stage_groundtruth", "stage_mappers", "stage_mdi", "stage_pairs"]
