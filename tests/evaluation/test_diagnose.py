"""The diagnostics re-make each validation pair as the pairs stage made it, in lanes where it used them."""

from __future__ import annotations

import dataclasses

import torch
from toy_task import CorridorTask

from metadagger.evaluation.diagnose import DiagnoseConfig, DiagnoseJob, diagnose_seed
from metadagger.imitation.bc import BCConfig
from metadagger.metal_dagger.lane_blocks import in_blocks
from metadagger.metal_dagger.pairs import PairConfig, collect_pairs
from metadagger.metal_dagger.pistar import PiStarConfig, train_pistar
from metadagger.metal_dagger.store import PairStore
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout

GT = PiStarConfig(
    seeds=(0, 1, 2, 3), eval_seeds=(100, 101), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3)
)
PAIRS = PairConfig(
    seeds=tuple(range(200, 205)),
    dagger_rounds=1,
    keep="all",
    bc=BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True),
    dagger_bc=BCConfig(lr=1e-2, batch_size=10, epochs=2, head_only=True),
    lanes=3,
)


def test_pairs_made_in_lanes_are_made_again_in_lanes_of_the_same_width(tmp_path):
    layout = RunLayout(tmp_path)
    train_pistar(CorridorTask(), GT, layout, progress=False)
    collect_pairs(CorridorTask(), layout, PAIRS, StageOptions(workers=1, progress=False))
    jobs = [
        DiagnoseJob(
            task=CorridorTask(),
            pistar=str(layout.pistar),
            seed=seed,
            pairs=PAIRS,
            config=DiagnoseConfig(states=4),
            methods=("states",),
        )
        for seed in PAIRS.seeds[1:]  # blocks other than the pairs stage's: a pair does not depend on its block
    ]
    work, blocks = in_blocks(diagnose_seed, jobs, PAIRS.lanes)
    results = [result for block in blocks for result in work(block)]
    w_bc, w_da = PairStore(layout.pairs_dir).load(PAIRS.seeds[1:])
    for i, result in enumerate(results):
        states = result["tensors"]["states"]
        assert torch.equal(states["w_bc"], w_bc[i]) and torch.equal(states["w_da"], w_da[i])
    # made alone, at batch 1, the same pair rounds its last bits otherwise: diagnose must not do that
    alone = diagnose_seed(dataclasses.replace(jobs[0], pairs=dataclasses.replace(PAIRS, lanes=1)))["tensors"]
    assert not torch.equal(alone["states"]["w_da"], w_da[0])
