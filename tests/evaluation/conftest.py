"""A toy corridor run with pi* and the pi*-head control: what the benchmark and the videos start from."""

from __future__ import annotations

import pytest
from toy_task import CorridorTask

from metadagger.imitation.bc import BCConfig
from metadagger.mapping.mappers import Mapper
from metadagger.metal.groundtruth import GroundTruthConfig, train_groundtruth
from metadagger.policies import load_policy
from metadagger.runfolder.layout import RunLayout

GT = GroundTruthConfig(
    seeds=(0, 1, 2, 3), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3)
)


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory) -> RunLayout:
    """A run folder (one per test module) holding pi* and the pi*-head mapper."""
    layout = RunLayout(tmp_path_factory.mktemp("toy"))
    train_groundtruth(CorridorTask(), GT, layout, progress=False)
    Mapper.pistar_head(load_policy(layout.groundtruth).head_vector()).save(layout.mapper("pistar-head"))
    return layout
