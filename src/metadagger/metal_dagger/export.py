"""A run's episodes as a Minari dataset (``metadagger export``).

``demos``: the expert's demonstration of each seed. ``dagger``: the learner's rollouts of the
per-seed DAgger rounds the pairs were made from; ``pairs-data``: those and the demonstrations,
everything each pair was fit on. The pair procedure is re-run per seed in parallel (it is
deterministic) and its heads are checked bit for bit against the stored pair, so the exported
episodes are exactly the data the stored pairs came from. Episodes are written in seed order
(demonstration first, then rounds), so the same run and seeds give the same dataset.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from metadagger.errors import UserError
from metadagger.imitation.minari_io import RecordedEpisode, check_new_dataset_name, write_dataset
from metadagger.imitation.rollouts import rollout
from metadagger.metal_dagger.pairs import PairConfig, pair_stamp, run_pair
from metadagger.metal_dagger.pistar import load_pistar
from metadagger.metal_dagger.store import PairStore
from metadagger.runfolder.driver import SeedJob, StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks.base import Task
from metadagger.utils.executors import in_order, make_executor
from metadagger.utils.progress import progress_bar
from metadagger.version import __version__, source_revision

EXPORTS = ("demos", "dagger", "pairs-data")
FORMATS = ("minari",)
#: The dataset's author when none is given.
DEFAULT_AUTHOR = "metadagger"


@dataclass(frozen=True)
class ExportJob(SeedJob):
    """One seed's episodes to export."""

    config: PairConfig
    content: str


def seed_episodes(job: ExportJob) -> dict[str, Any]:
    """The episodes of one seed (see the module docstring); with the pair's heads unless ``demos``."""
    if job.content == "demos":
        env = job.task.make_env()
        try:
            return {"seed": job.seed, "episodes": [RecordedEpisode(rollout(env, seed=job.seed, policy=None), round=0)]}
        finally:
            env.close()
    episodes: list[RecordedEpisode] = []
    pair = run_pair(
        job.task,
        job.pistar,
        job.seed,
        job.config,
        on_episode=lambda round_idx, trajectory: episodes.append(RecordedEpisode(trajectory, round=round_idx)),
    )
    if job.content == "dagger":
        episodes = [e for e in episodes if e.round > 0]
    return {"seed": job.seed, "episodes": episodes, "w_bc": pair.w_bc, "w_da": pair.w_da}


def check_export(content: str, fmt: str, name: str) -> None:
    """Raise a :class:`UserError` for an unknown ``content`` or format, or a taken or malformed name."""
    if content not in EXPORTS:
        raise UserError(f"--content {content!r} is not an export; expected one of {', '.join(EXPORTS)}")
    if fmt not in FORMATS:
        raise UserError(f"--format {fmt!r} is not supported; expected one of {', '.join(FORMATS)}")
    check_new_dataset_name(name)


def export_run(
    task: Task,
    layout: RunLayout,
    config: PairConfig,
    *,
    content: str,
    name: str,
    seeds: Sequence[int],
    author: str = DEFAULT_AUTHOR,
    author_email: str | None = None,
    options: StageOptions = StageOptions(),
) -> dict[str, Any]:
    """Write the run's ``content`` episodes of ``seeds`` as the Minari dataset ``name``, naming the
    algorithm that made them, its ``author`` and the code (metadagger's version and commit).

    Returns:
        ``dataset`` (its folder), ``episodes``, ``steps`` and ``checked`` (seeds whose re-run pair
        equalled the stored one bit for bit).

    Raises:
        UserError: bad ``content`` or name, no seeds, or no pi* (every export but ``demos`` needs it).
        RuntimeError: a re-run pair differs from the stored one (the run's code or inputs changed).
    """
    check_export(content, "minari", name)
    if not seeds:
        raise UserError("no seeds to export; pass --seeds or give the run pair seeds")
    if content != "demos":
        load_pistar(layout)  # a missing or corrupt pi* is named before any work
    stored = _stored_pairs(task, layout, config, seeds) if content != "demos" else {}
    jobs = [
        ExportJob(task=task, pistar=str(layout.pistar), seed=s, methods=(content,), config=config, content=content)
        for s in seeds
    ]
    counts = {"episodes": 0, "steps": 0, "checked": 0}

    def chunks(results: Iterable[dict[str, Any]]) -> Iterator[list[RecordedEpisode]]:
        for result in results:
            if result["seed"] in stored:
                _check_pair(result, *stored[result["seed"]])
                counts["checked"] += 1
            counts["episodes"] += len(result["episodes"])
            counts["steps"] += sum(e.trajectory.steps for e in result["episodes"])
            yield result["episodes"]

    env = task.make_env()
    spaces = {"observation_space": env.observation_space, "action_space": env.action_space}
    env.close()
    with make_executor(options.executor, workers=options.workers, address=options.address) as pool:
        results = progress_bar(
            in_order(pool.imap_unordered(seed_episodes, jobs), [j.seed for j in jobs], key=_seed_of),
            total=len(jobs),
            desc=f"export {content}",
            enabled=options.progress,
        )
        folder = write_dataset(
            name,
            chunks(results),
            **spaces,
            algorithm=f"metadagger {__version__} {content}: {_ALGORITHMS[content]}",
            description=f"{task.name}: {_DESCRIPTIONS[content]} of seeds {seeds[0]}..{seeds[-1]} "
            f"({len(seeds)} seeds), from run {layout.root}",
            author=author,
            author_email=author_email,
            code_permalink=code_permalink(),
        )
    return {"dataset": str(folder), **counts}


#: What made each export's actions and labels (the dataset's ``algorithm_name``).
_ALGORITHMS = {
    "demos": "the task's expert drives every step",
    "dagger": "MetaL DAgger's per-seed DAgger (pi*'s frozen trunk, a head per seed), every visited state labelled",
    "pairs-data": "MetaL DAgger's pairs: the expert's demonstration, then per-seed DAgger",
}


def code_permalink() -> str:
    """The code that made an export: metadagger's version and the commit it ran from."""
    revision = source_revision()
    return (
        f"metadagger {__version__}, commit {revision}" if revision else f"metadagger {__version__} (not a git checkout)"
    )


_DESCRIPTIONS = {
    "demos": "the expert's demonstrations",
    "dagger": "the learner's per-seed DAgger rollouts (infos: expert_label, queried, round, seed)",
    "pairs-data": "each pair's demonstration (round 0) and per-seed DAgger rollouts (infos: expert_label, queried, "
    "round, seed)",
}


def _stored_pairs(
    task: Task, layout: RunLayout, config: PairConfig, seeds: Sequence[int]
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The stored pairs among ``seeds`` made from today's pi* and settings."""
    if not layout.pairs_dir.is_dir():
        return {}
    stamp = pair_stamp(task, layout, config)
    store = PairStore(layout.pairs_dir)
    wanted = set(seeds)
    current = [s for s, stamps in store.stamps().items() if stamps["pair"] == stamp and s in wanted]
    if not current:
        return {}
    w_bc, w_da = store.load(current)
    return {s: (w_bc[i].numpy(), w_da[i].numpy()) for i, s in enumerate(current)}


def _seed_of(result: dict[str, Any]) -> int:
    return result["seed"]


def _check_pair(result: dict[str, Any], w_bc: np.ndarray, w_da: np.ndarray) -> None:
    if not (np.array_equal(result["w_bc"], w_bc) and np.array_equal(result["w_da"], w_da)):
        raise RuntimeError(
            f"seed {result['seed']}: the re-run pair differs from the stored one, so the episodes would not be "
            "the data it was fit on; the code changed since the pairs were collected"
        )
