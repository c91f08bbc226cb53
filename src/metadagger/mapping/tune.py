"""Mapper hyperparameter search with Optuna (``metadagger tune``; docs/tuning.md).

A study searches the :class:`~metadagger.mapping.config.MapperConfig` fields of one kind trained by
Adam (:mod:`metadagger.mapping.search_space`). A trial trains the trial's config on the training pairs of the run's
split and scores it on the split's *validation pairs* (a share of the pair seeds), with the
number ``curves.csv`` reports as ``val_mse_weights``: the whole mapping's MSE in original weight
units. Evaluation seeds are never read.

Only the driver touches the study (SQLite, ``RUN/tune/<kind>.db``): it asks for a batch of
``workers`` trials with Optuna's ask-and-tell interface, the executor trains them (in memory, so
Ray workers need neither optuna nor the run folder), and the driver tells the results in trial
order. The sampler of each batch is a :class:`optuna.samplers.TPESampler` seeded from the study
seed and the number of trials completed before the batch, so the same seed and worker count give
the same study, killed and resumed or not.

Resume: a trial a killed study left running is marked failed and its params are queued again
(user attribute ``retry_of``); the queued trials run first, alone in their batch, so the study
rejoins the batches an uninterrupted run would have made. Completed trials are never re-run.
Trial 0 of a new study is the base config itself (when the space can express it), so the best
trial is never worse than the settings the run already had.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from metadagger.errors import DivergedError, UserError
from metadagger.mapping.config import MapperConfig
from metadagger.mapping.search_space import (
    baseline_params,
    check_tunable,
    config_overrides,
    import_optuna,
    param_field,
    search_space,
    trial_config,
)
from metadagger.mapping.train import evaluate_mapping, fit_mapper, mapper_stamp
from metadagger.metal_dagger.store import PairSplit
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.stamps import describe_changes, stamp_of
from metadagger.utils.executors import in_order, make_executor
from metadagger.utils.io import write_text
from metadagger.utils.yaml_config import dump_yaml, to_dict

__all__ = [
    "TrialJob",
    "TuneResult",
    "score_trial",
    "tune_mapper",
]

STUDY_NAME = "mapper"
"""The study's name inside its database (one study per file)."""
_METRICS = ("relative_mse", "cosine", "cosine_update")
"""evaluate_mapping's other numbers, kept with each trial (the value is its ``mse``)."""


@dataclass(frozen=True)
class TrialJob:
    """One trial's work for a worker: train ``config`` on ``split``'s training pairs, score it on
    its validation pairs."""

    number: int
    """The trial's number in the study."""
    config: MapperConfig
    split: PairSplit

    def __repr__(self) -> str:  # how executor errors name the item (not its tensors)
        return f"trial {self.number}"


def score_trial(job: TrialJob) -> dict[str, Any]:
    """Train one trial's mapper in memory and score it on the validation pairs: ``number`` and
    :func:`~metadagger.mapping.train.evaluate_mapping`'s metrics (``mse`` is the score); a mapper
    whose training diverged gives ``number`` and ``diverged`` (the error's message) instead."""
    split = job.split
    try:
        mapper, _ = fit_mapper(split, job.config, progress=False)
    except DivergedError as exc:
        return {"number": job.number, "diverged": str(exc)}
    return {
        "number": job.number,
        **evaluate_mapping(
            mapper, split.w_bc_val, split.w_da_val, mean_da=split.w_da_train.mean(0), context=split.context_val
        ),
    }


@dataclass(frozen=True)
class TuneResult:
    """What a study found (also written to its summary YAML)."""

    kind: str
    completed: int
    """Completed trials in the study."""
    ran: int
    """Trials this call evaluated (re-runs of interrupted ones included)."""
    best_trial: int
    best_value: float
    """The best trial's validation MSE in original weight units."""
    baseline_value: float | None
    """Trial 0's value (the base config), None when the space could not express it."""
    overrides: dict[str, Any]
    """The whole ``mappers.<kind>`` section: the run's overrides with the best trial's fields."""
    set_item: str
    """``mappers.<kind>={...}``: the ``--set`` item that applies ``overrides``."""
    study: Path
    summary: Path


def tune_mapper(
    split: PairSplit,
    base: MapperConfig,
    *,
    study: str | Path,
    summary: str | Path,
    trials: int,
    seed: int = 0,
    base_overrides: Mapping[str, Any] | None = None,
    options: StageOptions = StageOptions(),
) -> TuneResult:
    """Run (or resume) the study of ``base.kind`` until it holds ``trials`` completed trials.

    Args:
        split: the run's split; trials train on its training pairs and are scored on its
            validation pairs.
        base: the run's config of the kind; trials change the fields of :func:`search_space`,
            the others (batch size, seed, ...) are the study's fixed settings.
        study: the SQLite file of the study (created, or resumed).
        summary: the YAML file the best trial is written to (rewritten after every trial).
        trials: completed trials the study should hold in total.
        seed: seeds the sampler.
        base_overrides: the run's ``mappers.<kind>`` section, which the best trial's fields join.
        options: executor and workers (a batch is one trial per worker), ``rebuild`` (delete the
            study and start a new one), ``progress`` (one line per finished trial).

    Raises:
        UserError: an untunable kind, bad ``trials`` or ``seed``, no validation pairs, Optuna
            missing, or (without ``rebuild``) a study made from other pairs or settings.
    """
    check_tunable(base.kind)
    for name, value, low in (("trials", trials, 1), ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise UserError(f"{name} must be an integer >= {low}, got {value!r}")
    if not split.val_seeds:
        raise UserError(
            "tuning scores trials on the validation pairs, but the split has none; set pairs.val_fraction above 0 "
            "(e.g. --set pairs.val_fraction=0.2)"
        )
    optuna = import_optuna()
    study_path, summary_path = Path(study), Path(summary)
    if options.rebuild:
        for path in (
            summary_path,
            *(study_path.with_name(study_path.name + s) for s in ("", "-journal", "-wal", "-shm")),
        ):
            path.unlink(missing_ok=True)
    study_path.parent.mkdir(parents=True, exist_ok=True)
    stamp = {"kind": base.kind, "seed": seed, "pairs_fingerprint": mapper_stamp(split, base)["pairs_fingerprint"]}
    with _quiet(optuna):
        storage = _storage(optuna, study_path)
        space = _open_study(optuna, storage, study_path, base, stamp)
        made_from = {
            **stamp,
            "base": _base_stamp(base, space),
            "train_pairs": len(split.train_seeds),
            "val_seeds": list(split.val_seeds),
            "space": {name: _describe(d) for name, d in space.items()},
        }
        context = _Context(
            optuna, storage, space, base, split, dict(base_overrides or {}), made_from, study_path, summary_path
        )
        ran = _run(context, trials=trials, seed=seed, options=options)
        return _write_summary(context, ran)


@dataclass(frozen=True)
class _Context:
    """What the study loop and its summary share."""

    optuna: Any
    storage: Any
    space: dict[str, Any]
    base: MapperConfig
    split: PairSplit
    base_overrides: dict[str, Any]
    made_from: dict[str, Any]
    study_path: Path
    summary_path: Path

    def load(self, sampler: Any = None) -> Any:
        return self.optuna.load_study(study_name=STUDY_NAME, storage=self.storage, sampler=sampler)


def _storage(optuna: Any, path: Path) -> Any:
    from sqlalchemy.exc import DatabaseError  # an Optuna dependency

    try:
        return optuna.storages.RDBStorage(f"sqlite:///{path.resolve()}")
    except DatabaseError as exc:
        reason = str(exc.orig or exc).splitlines()[0]
        raise UserError(
            f"{path} is not an Optuna study ({reason}); pass --rebuild to delete it and start a new study"
        ) from None


def _open_study(optuna: Any, storage: Any, path: Path, base: MapperConfig, stamp: dict[str, Any]) -> dict[str, Any]:
    """Create the study (its stamp, space and trial 0) or check an existing one; return its space."""
    study = optuna.create_study(study_name=STUDY_NAME, storage=storage, direction="minimize", load_if_exists=True)
    attrs = study.user_attrs
    if "space" not in attrs:  # new, or killed before its space (stored last) was: it has no trials yet
        space = search_space(base.kind, base)
        baseline = baseline_params(base, space)
        if baseline is not None:
            study.enqueue_trial(baseline, user_attrs={"baseline": True}, skip_if_exists=True)
        study.set_user_attr("stamp", {**stamp, "base": _base_stamp(base, space)})
        study.set_user_attr("space", {name: _distribution_data(optuna, d) for name, d in space.items()})
        return space
    space = {name: optuna.distributions.json_to_distribution(json.dumps(data)) for name, data in attrs["space"].items()}
    changes = describe_changes(attrs["stamp"], {**stamp, "base": _base_stamp(base, space)})
    if changes:
        raise UserError(
            f"{path} holds a study made from other inputs ({'; '.join(changes)}); pass --rebuild to delete it "
            "and start a new study, or restore those inputs to resume it"
        )
    return space


def _base_stamp(base: MapperConfig, space: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of ``base`` no trial changes: they shape every trial, so a study resumes only
    with the same ones (and ``--apply``, which writes only tuned fields, keeps them)."""
    tuned = {param_field(name) for name in space}
    return {name: value for name, value in stamp_of(base).items() if name not in tuned}


def _distribution_data(optuna: Any, distribution: Any) -> dict[str, Any]:
    return json.loads(optuna.distributions.distribution_to_json(distribution))


def _describe(distribution: Any) -> str | list[Any]:
    """A distribution as the summary shows it: its choices, or ``low..high`` (``log`` scale)."""
    choices = getattr(distribution, "choices", None)
    if choices is not None:
        return list(choices)
    return f"{distribution.low:g}..{distribution.high:g}" + (" log" if distribution.log else "")


def _run(context: _Context, *, trials: int, seed: int, options: StageOptions) -> int:
    """Evaluate batches until ``trials`` trials are complete; returns how many ran."""
    state = context.optuna.trial.TrialState
    _requeue_interrupted(context.load(), state)

    def completed() -> int:
        """Trials done: complete ones and those whose training diverged (failed, never retried)."""
        trials = context.load().get_trials(deepcopy=False, states=(state.COMPLETE, state.FAIL))
        return sum(t.state == state.COMPLETE or "diverged" in t.user_attrs for t in trials)

    if completed() >= trials:
        return 0  # no executor (nor Ray cluster) for a study that is done
    ran, started = 0, time.monotonic()
    with make_executor(options.executor, workers=options.workers, address=options.address) as pool:
        while (done := completed()) < trials:
            # a fresh sampler per batch, seeded by the study seed and the trials done before it:
            # Optuna does not store a sampler's state, so this is what makes a resumed study the same
            sampler_seed = int(np.random.SeedSequence([seed, done]).generate_state(1)[0])
            study = context.load(context.optuna.samplers.TPESampler(seed=sampler_seed))
            retries = sum("retry_of" in t.user_attrs for t in study.get_trials(deepcopy=False, states=(state.WAITING,)))
            asked = [study.ask(context.space) for _ in range(min(retries or pool.workers, trials - done))]
            jobs = [TrialJob(t.number, trial_config(context.base, t.params), context.split) for t in asked]
            # told in trial order: the same study every time
            results = in_order(pool.imap_unordered(score_trial, jobs), [t.number for t in asked], key=_number_of)
            for told, result in enumerate(results, 1):  # consumed to the end: an abandoned one closes the pool
                trial = asked[told - 1]
                value = _tell(study, trial, result, state)
                ran += 1
                if "diverged" in result:  # a failed trial: the study goes on without it
                    if options.progress:
                        print(
                            f"tune/{context.base.kind}: trial {trial.number} diverged ({done + told}/{trials}): "
                            f"{result['diverged']}",
                            file=sys.stderr,
                            flush=True,
                        )
                    continue
                summary = _write_summary(context, ran)
                if options.progress:
                    print(
                        f"tune/{summary.kind}: trial {trial.number}: {value:.6g} ({done + told}/{trials}, "
                        f"{time.monotonic() - started:.0f}s); best {summary.best_value:.6g} (trial "
                        f"{summary.best_trial})",
                        file=sys.stderr,
                        flush=True,
                    )  # a line per trial: trials take minutes
    return ran


def _number_of(result: dict[str, Any]) -> int:
    return result["number"]


def _requeue_interrupted(study: Any, state: Any) -> None:
    """Fail the trials a killed study left running and queue their params again (once), so they
    are re-run first; a trial killed before all its params were drawn was never sent to a worker
    and is only failed."""
    queued = {t.user_attrs.get("retry_of") for t in study.get_trials(deepcopy=False, states=(state.WAITING,))}
    space = set(study.user_attrs["space"])
    for trial in study.get_trials(deepcopy=False, states=(state.RUNNING,)):
        if trial.number not in queued and set(trial.params) == space:
            study.enqueue_trial(trial.params, user_attrs={**trial.user_attrs, "retry_of": trial.number})
        study.tell(trial.number, state=state.FAIL)


def _tell(study: Any, trial: Any, metrics: dict[str, Any], state: Any) -> float:
    """Record a trial's metrics and return its value. A mapper whose training diverged is a failed
    trial (its message kept as the user attribute ``diverged``) and returns +inf; a trained mapper
    whose error is not finite scores +inf, the worst value, as a completed trial."""
    if "diverged" in metrics:
        trial.set_user_attr("diverged", metrics["diverged"])
        study.tell(trial, state=state.FAIL)
        return math.inf
    for name in _METRICS:
        trial.set_user_attr(name, metrics[name])
    value = metrics["mse"] if math.isfinite(metrics["mse"]) else math.inf
    study.tell(trial, value)
    return value


def _write_summary(context: _Context, ran: int) -> TuneResult:
    """Write the study's best trial and what the study was made from to the summary YAML."""
    study = context.load()
    complete = study.get_trials(deepcopy=False, states=(context.optuna.trial.TrialState.COMPLETE,))
    if not complete:
        raise UserError(
            f"every trial of the {context.base.kind} study so far diverged (the first: "
            f"{study.trials[0].user_attrs.get('diverged', 'no message')}); narrow the search space to smaller "
            "learning rates"
        )
    best = study.best_trial
    baseline = next((t for t in complete if t.user_attrs.get("baseline")), None)
    kind = context.base.kind
    overrides = to_dict({**context.base_overrides, **config_overrides(best.params)})
    flow = yaml.safe_dump(overrides, default_flow_style=True, sort_keys=False, width=math.inf).strip()
    result = TuneResult(
        kind=kind,
        completed=len(complete),
        ran=ran,
        best_trial=best.number,
        best_value=best.value,
        baseline_value=None if baseline is None else baseline.value,
        overrides=overrides,
        set_item=f"mappers.{kind}={flow}",
        study=context.study_path,
        summary=context.summary_path,
    )
    write_text(
        context.summary_path,
        dump_yaml(
            {
                "kind": kind,
                "study": str(context.study_path),
                "completed_trials": result.completed,
                "best": {
                    "trial": best.number,
                    "value": best.value,
                    **{m: best.user_attrs[m] for m in _METRICS},
                    "params": best.params,
                },
                "baseline": None if baseline is None else {"trial": baseline.number, "value": baseline.value},
                "overrides": overrides,
                "set": result.set_item,
                "made_from": context.made_from,
            }
        ),
    )
    return result


@contextlib.contextmanager
def _quiet(optuna: Any) -> Iterator[None]:
    """Optuna's own INFO lines off (our progress lines say the same), restored afterwards."""
    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(verbosity)
