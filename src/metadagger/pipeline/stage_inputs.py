"""What a stage reads of the stages before it, read in one place and checked current.

A stage declares its inputs in one call, :func:`stage_inputs`: the task, pi*, and, where it
reads them, the kept pairs' split and the mappers of some kinds. Each is checked to be complete
and made from the run's config (the stamps of the stage that made it,
:mod:`metadagger.runfolder.stamps`); a missing or stale one is one line naming the command that
makes it again. Upstream of every input is pi*, so pi* is always read; a mapper's stamp names the
pairs it learned from, so a stamped mapper reads the pairs too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from metadagger.errors import UserError
from metadagger.imitation.gate_registry import check_gates_serve
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.train import mapper_stamp
from metadagger.metal_dagger.pairs import OUTCOMES, pair_status
from metadagger.metal_dagger.pistar import load_pistar, pistar_changes, pistar_rates
from metadagger.metal_dagger.store import PairSplit, PairStore, validation_size
from metadagger.pipeline.run_config import RunConfig
from metadagger.policies import Policy
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import describe_changes
from metadagger.tasks import make_task
from metadagger.tasks.base import Task
from metadagger.tasks.checks import check_task_code
from metadagger.utils.io import read_json


@dataclass(frozen=True)
class StageInputs:
    """A stage's inputs, each made from the run's config."""

    task: Task
    """The run's task."""
    pistar: Policy
    """pi*, loaded."""
    split: PairSplit | None
    """The kept pairs of ``pairs.seeds``, split into training and validation; None where the stage
    does not read the pairs."""


def stage_inputs(
    layout: RunLayout,
    config: RunConfig,
    *,
    pairs: bool = False,
    mappers: Sequence[str] = (),
    checked: bool = False,
) -> StageInputs:
    """The inputs a stage reads: the task and pi*, and the kept pairs (``pairs``) and the mappers
    of ``mappers`` where it reads them, each checked to exist and to be made from ``config``.
    ``checked``: the task's code also passes the cheap checks (the stages that roll out first).

    Raises:
        UserError: an input is missing or was made from other inputs, naming the command that
            makes it again.
    """
    task = run_task(config, checked=checked)
    pistar = current_pistar(layout, config, task)
    split = current_split(layout, config, task) if pairs else None
    for kind in mappers:
        path = layout.mapper(kind)
        if not path.is_file():
            raise UserError(
                f"mapper {kind} not trained yet (no {path}); run `metadagger train-mapper --out {layout.root} --kind "
                "all` first"
            )
        mapper = load_mapper(path)
        if not mapper.stamp:  # a mapper saved by hand, without a stamp, is taken as it is
            continue
        split = split or current_split(layout, config, task)
        changes = describe_changes(mapper.stamp, mapper_stamp(split, config.mapper_config(kind), pistar.head_vector()))
        if changes:
            raise UserError(
                f"mapper {kind} in {layout.mapper_dir(kind)} was made from other inputs ({'; '.join(changes)}); "
                f"run `metadagger train-mapper --out {layout.root} --kind {kind} --rebuild` or `metadagger reproduce`"
            )
    return StageInputs(task=task, pistar=pistar, split=split if pairs else None)


def run_task(config: RunConfig, *, checked: bool = False) -> Task:
    """The task a run was configured with; ``checked``: its code passed the cheap checks
    (:func:`~metadagger.tasks.checks.check_task_code`), so that no wrong observation is ever
    trained on and a mistake in it is one line before any work. A benchmark gate that cannot serve
    the task (a class distribution read on action vectors), or DART's noise that is no probability
    on classes, is one line too."""
    task = make_task(config.task, **config.task_kwargs)
    if config.benchmark is not None:
        check_gates_serve(config.benchmark.gated(), discrete=task.is_discrete, task=config.task)
        config.benchmark.check_serves(discrete=task.is_discrete, task=config.task)
    if checked:
        check_task_code(task)
    return task


def current_pistar(layout: RunLayout, config: RunConfig, task: Task) -> Policy:
    """pi*, checked to exist, to load and to be made from this run's config."""
    pistar = load_pistar(layout)  # a corrupt file is named even when no work is left
    changes = pistar_changes(task, config.pistar, layout)
    if changes:
        raise UserError(
            f"pi* in {layout.pistar_dir} was made from another config ({'; '.join(changes)}); "
            f"run `metadagger reproduce` to rebuild it and what depends on it"
        )
    return pistar


def current_split(layout: RunLayout, config: RunConfig, task: Task) -> PairSplit:
    """The kept pairs of ``pairs.seeds``, split; every seed must have a pair made from today's pi*
    and pair settings."""
    missing, changes = pair_status(task, layout, config.pairs)
    if missing:
        PairStore(layout.pairs_dir).check_readable(
            missing, fix=f"run `metadagger pairs --out {layout.root}`, which collects that pair again"
        )
        why = f"made from other inputs ({'; '.join(changes)})" if changes else "not collected"
        raise UserError(
            f"{len(missing)} of {len(config.pairs.seeds)} seeds of pairs.seeds have no current pair (e.g. "
            f"{missing[0]}: {why}); "
            f"run `metadagger pairs --out {layout.root}`"
            + (" --rebuild" if changes else "")
            + " or `metadagger reproduce` first"
        )
    store = PairStore(layout.pairs_dir)
    kept = sum(1 for r in store.records() if r.get("kept") is True and r["seed"] in set(config.pairs.seeds))
    if kept - validation_size(kept, config.pairs.val_fraction) < 2:
        raise UserError(
            f"only {kept} kept pairs (pairs.keep={config.pairs.keep}) in {layout.pairs_dir}, too few for a "
            f"training set with pairs.val_fraction={config.pairs.val_fraction:g}: {_pair_outcomes(layout)}; "
            "with few kept pairs, collect more pairs.seeds or relax pairs.keep; with none, make pi* stronger "
            '(docs/custom_task.md, "Making pi* work on a new task")'
        )
    return store.load_split(
        val_fraction=config.pairs.val_fraction, seed=config.split_seed, kept_only=True, seeds=config.pairs.seeds
    )


def _pair_outcomes(layout: RunLayout) -> str:
    """The pairs' outcome counts and pi*'s success rates, as a clause of an error line."""
    parts = []
    if layout.pairs_summary.is_file():
        summary = read_json(layout.pairs_summary, "the pairs' summary")
        counts = ", ".join(f"{name} {summary['outcomes'].get(name, 0)}" for name in OUTCOMES)
        parts.append(f"of {summary['seeds']} pair seeds: {counts}")
    if layout.pistar_metrics.is_file():
        metrics = read_json(layout.pistar_metrics, "pi*'s metrics")
        parts.append(f"pi*: {pistar_rates(metrics)}")
    return "; ".join(parts) or "no pairs summary yet"
