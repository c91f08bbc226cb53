"""Per-seed jobs of one protocol in blocks, each block's seeds stepped together in lockstep lanes.

A protocol's per-seed ``work`` (a pair, say) is left as it is: :func:`run_block` runs each job
of a block as a chain (:func:`~metadagger.imitation.lanes.run_chains`), and every
:class:`~metadagger.metal_dagger.method.SeedLearner` the job makes finds the chain's lane by itself.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from metadagger.imitation.lanes import Lane, Lanes, run_chains
from metadagger.metal_dagger.pistar import cached_pistar
from metadagger.utils.executors import default_workers


@dataclass(frozen=True)
class LaneBlock:
    """Per-seed jobs of one protocol run together: each job's ``work`` is a chain, its episodes in
    ``width`` lanes (:func:`run_block`)."""

    work: Callable[[Any], dict[str, Any]]
    jobs: tuple[Any, ...]
    width: int

    @property
    def seed(self) -> int:
        """The first job's seed (how an error names the block)."""
        return int(self.jobs[0].seed)


def in_blocks(
    work: Callable[[Any], dict[str, Any]], jobs: Sequence[Any], width: int, workers: int | None = None
) -> tuple[Callable, list]:
    """``(work, jobs)`` for the driver: with ``width`` above 1, blocks of consecutive jobs, each in
    lanes of ``width`` and run by :func:`run_block`, returning its jobs' results; else as they are.

    The blocks are as even as can be, and as many as the fewest that hold the jobs rounded up to a
    multiple of ``workers`` (default: the cores a local executor would use), so that no worker waits while another
    runs a last, lone block. A seed's results do not depend on which seeds share its block (an
    episode does not depend on its lane-mates, nor, at a width that is a multiple of 4, on its
    lane: docs/performance.md; and each seed has a learner of its own), so the cut changes the
    time a stage takes, never its numbers.
    """
    if width == 1:
        return work, list(jobs)
    blocks, start = [], 0
    for size in block_sizes(len(jobs), width, workers or default_workers()):
        blocks.append(LaneBlock(work, tuple(jobs[start : start + size]), width))
        start += size
    return run_block, blocks


def block_sizes(jobs: int, width: int, workers: int) -> list[int]:
    """How many of ``jobs`` each block holds: the fewest blocks of at most ``width`` that hold them,
    rounded up to a multiple of ``workers`` but never more blocks than jobs, as even as can be."""
    count = min(jobs, math.ceil(math.ceil(jobs / width) / workers) * workers)
    return [jobs * (i + 1) // count - jobs * i // count for i in range(count)]


def run_block(block: LaneBlock) -> list[dict[str, Any]]:
    """Each job of ``block`` as a chain, every :class:`~metadagger.metal_dagger.method.SeedLearner`
    it makes rolling out in the block's lanes through pi*'s trunk; the jobs' results in order."""
    first = block.jobs[0]
    with Lanes(first.task, cached_pistar(first.pistar).net, width=block.width) as lanes:
        return run_chains(lanes, [functools.partial(_job_chain, block.work, job) for job in block.jobs])


def _job_chain(work: Callable[[Any], dict[str, Any]], job: Any, lane: Lane) -> Any:
    return work(job)  # its learners find ``lane`` themselves (current_lane)
