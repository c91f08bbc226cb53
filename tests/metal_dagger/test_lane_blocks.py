from __future__ import annotations

import pytest

from metadagger.metal_dagger.lane_blocks import LaneBlock, block_sizes, in_blocks, run_block


@pytest.mark.parametrize("jobs", [1, 2, 3, 7, 20, 30, 33, 64, 65, 480])
@pytest.mark.parametrize("width", [2, 8, 16, 32])
@pytest.mark.parametrize("workers", [1, 2, 3, 16])
def test_blocks_are_even_fit_the_width_and_leave_no_worker_a_lone_last_block(jobs, width, workers):
    sizes = block_sizes(jobs, width, workers)
    assert sum(sizes) == jobs and max(sizes) <= width and max(sizes) - min(sizes) <= 1
    fewest = -(-jobs // width)
    # the fewest blocks, rounded up to a multiple of the workers, unless there are fewer jobs than that
    assert len(sizes) == jobs or (len(sizes) % workers == 0 and len(sizes) - fewest < workers)


def test_a_stage_at_width_8_on_20_seeds_and_2_workers_runs_4_blocks_of_5_not_8_8_4():
    assert block_sizes(20, 8, 2) == [5, 5, 5, 5]
    assert block_sizes(480, 32, 2) == [30] * 16  # not 15 blocks, the last one alone on a worker


def test_in_blocks_cuts_consecutive_jobs_in_order_and_keeps_width_1_as_it_is():
    def work(job):
        return {"seed": job}

    runner, blocks = in_blocks(work, list(range(20)), 8, workers=2)
    assert runner is run_block and all(isinstance(b, LaneBlock) and b.width == 8 for b in blocks)
    assert [list(b.jobs) for b in blocks] == [list(range(i, i + 5)) for i in range(0, 20, 5)]
    assert in_blocks(work, [3, 4], 1, workers=2) == (work, [3, 4])
    assert in_blocks(work, [], 8, workers=2) == (run_block, [])
