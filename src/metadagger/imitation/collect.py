"""Episodes of many seeds: one after another, chunks of seeds in a process pool, or in lockstep lanes."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from metadagger.imitation.lanes import EpisodeRequest, Lanes
from metadagger.imitation.rollouts import EarlyStop, Trajectory, rollout
from metadagger.policies import Policy
from metadagger.tasks.base import Task
from metadagger.utils.executors import in_order, make_executor
from metadagger.utils.progress import progress_bar


@dataclass(frozen=True)
class _Chunk:
    """Consecutive seeds of one :func:`collect` call, rolled out in one worker's env."""

    task: Task
    start: int
    """Index of the first seed in the call's seed list."""
    seeds: list[int]
    policy: Policy | None
    early_stop_factory: Callable[[], EarlyStop] | None
    max_steps: int | None
    each: Callable[[Trajectory], Any] | None
    lanes: int


def _collect_chunk(chunk: _Chunk) -> tuple[int, list[Any]]:
    return chunk.start, collect(
        chunk.task,
        chunk.seeds,
        policy=chunk.policy,
        early_stop_factory=chunk.early_stop_factory,
        max_steps=chunk.max_steps,
        each=chunk.each,
        lanes=chunk.lanes,
    )


def collect(
    task: Task,
    seeds: Iterable[int],
    *,
    policy: Policy | None,
    progress: bool = False,
    early_stop_factory: Callable[[], EarlyStop] | None = None,
    max_steps: int | None = None,
    workers: int = 1,
    each: Callable[[Trajectory], Any] | None = None,
    desc: str | None = None,
    lanes: int = 1,
) -> list[Any]:
    """One :func:`rollout` per seed, in seed order, in a learner env of ``task`` reused across seeds
    (or, with ``lanes`` above 1, stepped together in that many lanes).

    Args:
        task: the task whose learner env is used.
        seeds: reset seeds, one episode each.
        policy: the learner, or ``None`` for expert demonstrations.
        progress: show a progress bar.
        early_stop_factory: builds one :class:`EarlyStop` for this call (for each worker's chunk).
        max_steps: per-episode step cap (see :func:`rollout`).
        workers: with more than 1, consecutive chunks of seeds run in a local process pool, each
            in its own env; an episode depends only on its seed and the policy (tested), so the
            trajectories are the same as with 1.
        each: a top-level function applied to every trajectory as soon as it is made (in the
            worker); the call then returns its results instead of the trajectories, so images
            need neither travel back nor stay in memory (e.g. one summary row per episode).
        desc: the progress bar's name (default: "<task> rollouts").
        lanes: with a policy, step this many episodes in lockstep, one forward of the policy's
            trunk per step at this batch shape (:class:`~metadagger.imitation.lanes.Lanes`): the
            episodes depend on the width, never on the workers or on which seeds share a chunk.
            Early stops need ``lanes=1``.

    Returns:
        The trajectories (or ``each``'s results), one per seed, in the order of ``seeds``.
    """
    seeds = list(seeds)
    desc = desc or f"{task.name} rollouts"
    if workers > 1 and len(seeds) > 1:
        return _collect_in_pool(
            task,
            seeds,
            policy=policy,
            desc=desc,
            progress=progress,
            early_stop_factory=early_stop_factory,
            max_steps=max_steps,
            workers=workers,
            each=each,
            lanes=lanes,
        )
    if lanes > 1 and policy is not None:
        if early_stop_factory is not None:
            raise ValueError("collect: lanes step episodes without an early stop; pass lanes=1 with early_stop_factory")
        head = policy.head_vector().detach().numpy()
        requests = [EpisodeRequest(seed, head, max_steps=max_steps, keep_images=True) for seed in seeds]
        with Lanes(task, policy.net, width=lanes) as laned:
            # the features belong to the policy's trunk of this moment: a trajectory keeps its images only
            return laned.run(requests, each=lambda t: _without_features(t) if each is None else each(t))
    env = task.make_env()
    early_stop = early_stop_factory() if early_stop_factory is not None else None
    try:
        episodes = (
            rollout(env, seed=seed, policy=policy, max_steps=max_steps, early_stop=early_stop)
            for seed in progress_bar(seeds, desc=desc, enabled=progress, leave=False)
        )
        return [episode if each is None else each(episode) for episode in episodes]
    finally:
        env.close()


# Chunks per worker: enough that a slow chunk does not leave the other workers idle for long and
# that progress moves, few enough that building each chunk's env stays cheap.
_CHUNKS_PER_WORKER = 4


def _collect_in_pool(
    task: Task,
    seeds: list[int],
    *,
    policy: Policy | None,
    desc: str,
    progress: bool,
    early_stop_factory: Callable[[], EarlyStop] | None,
    max_steps: int | None,
    workers: int,
    each: Callable[[Trajectory], Any] | None,
    lanes: int,
) -> list[Any]:
    size = -(-len(seeds) // min(len(seeds), workers * _CHUNKS_PER_WORKER))
    chunks = [
        _Chunk(task, start, seeds[start : start + size], policy, early_stop_factory, max_steps, each, lanes)
        for start in range(0, len(seeds), size)
    ]
    results: list[Any] = []
    with make_executor("local", workers=min(workers, len(chunks))) as executor:
        done = in_order(executor.imap_unordered(_collect_chunk, chunks), [c.start for c in chunks], key=lambda r: r[0])
        for _, chunk in progress_bar(
            done,
            desc=f"{desc} ({len(seeds)} seeds in {len(chunks)} chunks)",
            enabled=progress,
            leave=False,
            total=len(chunks),
        ):
            results.extend(chunk)
    return results


def _without_features(trajectory: Trajectory) -> Trajectory:
    return dataclasses.replace(trajectory, features=None)
