"""The "ground truth" policy pi* (paper 3.4.1): one BC fit on expert demos of K seeds, then DAgger
rounds over all K seeds. Its layers 1..n-1 are frozen into every per-seed policy afterwards.

Artifacts (paths from :class:`~metadagger.runfolder.layout.RunLayout`): pi*, its metrics (success on its
own seeds and on unseen seeds), the stamp of the config it is made from (written first) and
per-round checkpoints, so a killed run resumes after its last finished fit. A pi* depends only on
the task it learns and its config, so the runs of one machine share it
(:mod:`~metadagger.runfolder.machine_cache`): a family's run takes the one its base task's run made.
"""

from __future__ import annotations

import datetime
import functools
import shutil
import time
from dataclasses import dataclass, field
from typing import Any

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, fit_or_resume
from metadagger.imitation.collect import collect
from metadagger.imitation.data import Dataset
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.lanes import check_lanes, lanes_stamp
from metadagger.imitation.metrics import summarize, wilson_interval
from metadagger.imitation.selection import EpochSelector
from metadagger.imitation.whole_policy_dagger import DAggerConfig, run_whole_policy_dagger
from metadagger.policies import Policy, load_policy, make_policy
from metadagger.runfolder import machine_cache
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import describe_changes, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import atomic_write, read_json, write_json
from metadagger.utils.kernels import kernel_stamp, machine_description
from metadagger.utils.progress import clock, note
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT
from metadagger.version import source_revision

CACHE_KIND = "pistar"
"""pi*'s kind in the machine's cache."""


@dataclass(frozen=True)
class PiStarConfig:
    """How pi* is trained and measured."""

    seeds: tuple[int, ...] = tuple(range(0, 20))
    """The K seeds whose demos and DAgger rollouts train pi*."""
    eval_seeds: tuple[int, ...] = tuple(range(900, 920))
    """Unseen seeds pi* is measured on (never used for pairs or evaluation)."""
    dagger_rounds: int = 5
    """DAgger rounds after the BC fit (the paper uses 5)."""
    bc: BCConfig = field(default_factory=lambda: BCConfig(lr=1e-3, batch_size=64, epochs=3))
    """The whole-policy fit done on the demos and again after every round."""
    seed: int = 0
    """Seed of pi*'s initial weights."""
    select_seeds: tuple[int, ...] = field(default=(), metadata=STAMPED_UNLESS_DEFAULT)
    """Early stopping on held-out seeds of pi*'s own: every ``select_every`` epochs of the BC fit
    (and after its last) pi* is rolled out on these seeds, and the epoch with the most successes
    (the later on a tie) is pi*. They must be none of ``seeds`` and ``eval_seeds``. Empty (the
    default): pi* is the last epoch's. Needs ``dagger_rounds: 0``."""
    select_every: int = field(default=4, metadata=STAMPED_UNLESS_DEFAULT)
    """Epochs between the checks of ``select_seeds``."""
    lanes: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """pi*'s own rollouts (DAgger rounds, selection checks, the success measures) stepped this
    many at a time in lockstep lanes, one forward of pi*'s trunk per step at this batch shape
    (:mod:`metadagger.imitation.lanes`); 1 rolls each episode out alone. pi* depends on it,
    never on the workers."""
    min_success: float = 0.2
    """The least success rate pi* must reach on ``eval_seeds`` before pairs are collected. With
    pi*'s trunk frozen, a seed's DAgger refit of the head rarely succeeds where pi* itself fails
    on most unseen seeds, so a weaker pi* leaves no kept pairs and the later stages would measure
    nothing (docs/custom_task.md, "Making pi* work on a new task"). 0 turns the check off (smoke
    presets). Not part of pi*'s stamp: it judges pi*, it does not make it."""

    @property
    def used_seeds(self) -> set[int]:
        """Every seed pi*'s stage rolls out: its training, held-out selection and unseen check seeds."""
        return set(self.seeds) | set(self.select_seeds) | set(self.eval_seeds)

    def __post_init__(self) -> None:
        check_lanes("pistar.lanes", self.lanes)
        if not self.seeds:
            raise UserError("pistar.seeds must not be empty")
        if set(self.seeds) & set(self.eval_seeds):
            raise UserError("pistar.eval_seeds must be unseen: they overlap pistar.seeds; pick disjoint ranges")
        if set(self.select_seeds) & (set(self.seeds) | set(self.eval_seeds)):
            raise UserError(
                "pistar.select_seeds must be held out: they overlap pistar.seeds or eval_seeds; pick disjoint ranges"
            )
        if self.select_seeds and self.dagger_rounds:
            raise UserError(
                "pistar.select_seeds chooses an epoch of the BC fit and needs dagger_rounds: 0; "
                "drop select_seeds or set dagger_rounds: 0"
            )
        if not isinstance(self.select_every, int) or isinstance(self.select_every, bool) or self.select_every < 1:
            raise UserError(f"pistar.select_every must be an integer >= 1, got {self.select_every!r}")
        if self.dagger_rounds < 0:
            raise UserError(f"pistar.dagger_rounds must be >= 0, got {self.dagger_rounds}")
        if (
            isinstance(self.min_success, bool)
            or not isinstance(self.min_success, (int, float))
            or not 0 <= self.min_success <= 1
        ):
            raise UserError(f"pistar.min_success must be a number in [0, 1], got {self.min_success!r}; e.g. 0.2")
        if self.bc.head_only:
            raise UserError("pistar.bc.head_only must be false: pi* trains the whole policy")


def pistar_stamp(task: Task, config: PiStarConfig) -> dict:
    """What pi* is made from: the task and every setting of its training."""
    return {
        **kernel_stamp(),
        **task_stamp(task),
        **stamp_of(config, drop=("min_success",)),
        **lanes_stamp(config.lanes),
    }


def pistar_cache_stamp(task: Task, config: PiStarConfig) -> dict:
    """What pi* is made from in any run: :func:`pistar_stamp` of the task pi* learns (a family's
    nominal member, so a family's run and its base task's share one pi*)."""
    return pistar_stamp(task.pistar_task(), config)


def pistar_changes(task: Task, config: PiStarConfig, layout: RunLayout) -> list[str]:
    """How the recorded pi* differs from one ``config`` would make (``[]``: the same, none yet, or a
    pi* put there by hand, without a stamp: downstream stamps still record its fingerprint)."""
    if not layout.pistar_stamp.is_file():
        return []
    return describe_changes(read_json(layout.pistar_stamp, "pi*'s stamp"), pistar_stamp(task, config))


def train_pistar(
    task: Task,
    config: PiStarConfig,
    layout: RunLayout,
    *,
    rebuild: bool = False,
    progress: bool = True,
    workers: int = 1,
) -> dict:
    """Train pi* (or reuse a finished one made from the same config) and return its metrics:
    ``own_seeds`` and ``unseen_seeds`` (:func:`~metadagger.imitation.metrics.summarize`), ``rounds``
    (:func:`~metadagger.imitation.whole_policy_dagger.run_whole_policy_dagger`'s records),
    ``bc_epoch_losses`` (the BC fit's loss per epoch; None when resumed from its checkpoint),
    ``expert_queries`` and, with ``select_seeds``, ``bc_selection``
    (:attr:`~metadagger.imitation.selection.EpochSelector.choice`; None when resumed). Its rollouts
    (demonstrations, DAgger rounds, the success checks) run in a pool of ``workers`` processes;
    the fits run in this one, on one thread (docs/architecture.md, "Determinism").

    Raises:
        UserError: the run's pi* (finished or not) was made from another config and ``rebuild``
            is off; the message names the fields that differ.
        CheckpointError: the finished pi* cannot be read back (deleting it retrains it, resuming
            from its round checkpoints).
    """
    changes = pistar_changes(task, config, layout)
    if changes and not rebuild:
        raise UserError(
            f"pi* in {layout.pistar_dir} was made from another config ({'; '.join(changes)}); "
            f"run `metadagger reproduce` (it rebuilds pi* and what depends on it) or use another --out"
        )
    if changes:
        shutil.rmtree(layout.pistar_dir)
    if layout.pistar.is_file() and layout.pistar_metrics.is_file():
        load_policy(layout.pistar)  # a damaged pi* is named here rather than reused
        _keep_in_cache(task, config, layout, seconds=None)
        return read_json(layout.pistar_metrics, "pi*'s metrics")
    write_json(layout.pistar_stamp, pistar_stamp(task, config))
    if _take_from_cache(task, config, layout, progress=progress):
        return read_json(layout.pistar_metrics, "pi*'s metrics")
    layout.pistar_origin.unlink(missing_ok=True)  # made here: no record of another run's
    started = time.perf_counter()
    task = task.pistar_task()  # a family's pi* learns its nominal member (docs/families.md)

    demos = collect(task, config.seeds, policy=None, progress=progress, workers=workers)
    data = Dataset.concat(*(t.to_dataset() for t in demos))
    policy = make_policy(task, seed=config.seed)
    selector = (
        EpochSelector(
            task,
            policy,
            config.select_seeds,
            every=config.select_every,
            epochs=config.bc.epochs,
            workers=workers,
            lanes=config.lanes,
            progress=progress,
        )
        if config.select_seeds
        else None
    )
    bc_losses = fit_or_resume(
        policy,
        data,
        config.bc,
        layout.pistar_rounds / "round_0.safetensors",
        progress=progress,
        selector=selector,
        called="pi*'s BC fit (pistar.bc)",
    )
    history = []
    if config.dagger_rounds:
        result = run_whole_policy_dagger(
            policy,
            task,
            config.seeds,
            initial=data,
            config=DAggerConfig(rounds=config.dagger_rounds, bc=config.bc),
            progress=progress,
            checkpoints=layout.pistar_rounds,
            workers=workers,
            lanes=config.lanes,
        )
        history = result.rounds
    own, unseen = (
        summarize(
            evaluate_policy(task, policy, seeds, label=label, progress=progress, workers=workers, lanes=config.lanes)
        )
        for seeds, label in ((config.seeds, "pi* on its seeds"), (config.eval_seeds, "pi* on unseen seeds"))
    )
    metrics = {
        "own_seeds": own,
        "unseen_seeds": unseen,
        "rounds": history,
        "bc_epoch_losses": bc_losses,
        "expert_queries": history[-1]["dagger/expert_queries"] if history else len(data),
    }
    if selector is not None:
        metrics["bc_selection"] = selector.choice if bc_losses is not None else None
    policy.save(layout.pistar)
    write_json(layout.pistar_metrics, metrics)
    _keep_in_cache(task, config, layout, seconds=time.perf_counter() - started)
    return metrics


def _take_from_cache(task: Task, config: PiStarConfig, layout: RunLayout, *, progress: bool) -> bool:
    """Copy the machine's cached pi* made from this config into the run, with ``origin.json`` saying
    where it was made; False when the cache holds none (or one that does not load)."""
    names = (layout.pistar.name, layout.pistar_metrics.name)
    entry = machine_cache.cached(CACHE_KIND, pistar_cache_stamp(task, config), names)
    if entry is None:
        return False
    try:
        load_policy(entry / layout.pistar.name)
    except UserError:  # a damaged entry (a CheckpointError) goes: pi* is made here and kept again
        shutil.rmtree(entry, ignore_errors=True)
        return False
    made = machine_cache.made_record(entry)
    write_json(layout.pistar_origin, {**made, "cache": str(entry)})
    for path in (layout.pistar, layout.pistar_metrics):  # the metrics last: they mark pi* finished
        atomic_write(path, lambda tmp, source=entry / path.name: shutil.copyfile(source, tmp))
    took = "" if made.get("seconds") is None else f" in {clock(made['seconds'])}"
    note(
        f"pi*: taken from the machine's cache, made by run {made.get('run')}{took} "
        f"({machine_cache.CACHE_ENV}={machine_cache.OFF} trains it here)",
        enabled=progress,
    )
    return True


def _keep_in_cache(task: Task, config: PiStarConfig, layout: RunLayout, *, seconds: float | None) -> None:
    """Put the run's finished pi* in the machine's cache (unless it came from there), with where and
    when it was made and its training's wall seconds (None: pi* finished in an earlier call, whose
    recorded stage time is taken)."""
    if layout.pistar_origin.is_file():
        return
    times = read_json(layout.stage_times, "the stage times").get("pistar", {}) if layout.stage_times.is_file() else {}
    earlier = float(times.get("earlier_seconds", times.get("total_seconds", 0.0)))  # the calls' before this one
    made: dict[str, Any] = {
        "run": str(layout.root.resolve()),
        "seconds": round(earlier + seconds, 3) if seconds is not None else (earlier or None),
        "commits": times.get("commits") if seconds is None else [source_revision() or "unknown"],
        "cpus": times.get("cpus") if seconds is None else [machine_description()["cpu"]],
        "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    files = {path.name: path for path in (layout.pistar, layout.pistar_metrics)}
    machine_cache.keep(CACHE_KIND, pistar_cache_stamp(task, config), files, made)


def pistar_rates(metrics: dict) -> str:
    """pi*'s success on its own and on its unseen seeds, with 95% Wilson intervals, as one line."""
    return "; ".join(
        f"{what} {_rate(metrics[key])}" for what, key in (("own seeds", "own_seeds"), ("unseen seeds", "unseen_seeds"))
    )


def _rate(summary: dict) -> str:
    low, high = wilson_interval(summary["successes"], summary["episodes"])
    share = summary["successes"] / max(summary["episodes"], 1)
    return f"{summary['successes']}/{summary['episodes']} ({share:.0%}, 95% interval {low:.0%}-{high:.0%})"


def check_pistar(metrics: dict, config: PiStarConfig, layout: RunLayout) -> None:
    """Raise a :class:`UserError` when pi*'s success on its unseen seeds is below
    ``config.min_success``: later stages would measure nothing."""
    unseen = metrics["unseen_seeds"]
    if unseen["success_rate"] >= config.min_success:
        return
    raise UserError(
        f"pi* in {layout.pistar_dir} is too weak to learn from: {pistar_rates(metrics)}, below "
        f"pistar.min_success={config.min_success:g} on unseen seeds; with its trunk frozen the per-seed DAgger "
        "refits would rarely succeed and the later stages would measure nothing; make pi* stronger (more "
        "pistar.seeds, pistar.bc.augment_shift, more epochs or dagger_rounds, policy_arch; "
        'docs/custom_task.md, "Making pi* work on a new task"), or set pistar.min_success=0 to go on anyway'
    )


def load_pistar(layout: RunLayout) -> Policy:
    """The run's pi*; a missing or unreadable file is a :class:`UserError` naming it and the fix."""
    if not layout.pistar.is_file():
        raise UserError(f"pi* not found at {layout.pistar}; run `metadagger pistar --out {layout.root}` first")
    return load_policy(layout.pistar)


@functools.lru_cache(maxsize=2)
def cached_pistar(path: str) -> Policy:
    """pi* loaded once per worker process (callers copy it before changing it)."""
    return load_policy(path)


def head_from_pistar(pistar: Policy, seed: int) -> Policy:
    """A copy of pi* with its trunk frozen and its head re-initialised from ``seed``."""
    policy = pistar.copy()
    policy.freeze_trunk()
    policy.reset_head(seed)
    return policy
