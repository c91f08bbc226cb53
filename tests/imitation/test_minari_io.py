"""Reading Minari datasets: a damaged data file is one line naming the dataset, its data and the fix."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from metadagger.errors import UserError
from metadagger.imitation.minari_io import read_demonstrations

IMAGE = gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)
ACTIONS = gym.spaces.Discrete(3)


@pytest.fixture
def dataset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The data folder of a local 1-episode dataset ``test/damaged-v0``."""
    minari = pytest.importorskip("minari")
    from minari.data_collector import EpisodeBuffer

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    rng = np.random.default_rng(0)
    buffer = EpisodeBuffer(
        id=0,
        seed=0,
        observations=rng.integers(0, 256, (5, 8, 8, 3), dtype=np.uint8),
        actions=rng.integers(0, 3, 4),
        rewards=[0.0] * 4,
        terminations=[False] * 3 + [True],
        truncations=[False] * 4,
    )
    minari.create_dataset_from_buffers("test/damaged-v0", [buffer], observation_space=IMAGE, action_space=ACTIONS)
    return tmp_path / "datasets" / "test" / "damaged-v0" / "data"


def test_an_intact_dataset_reads_its_labelled_states(dataset: Path) -> None:
    assert len(read_demonstrations("test/damaged-v0", observation_space=IMAGE, action_space=ACTIONS)) == 4


@pytest.mark.parametrize("damage", [lambda b: b[: len(b) // 2], lambda b: b"x\n"], ids=["truncated", "garbage"])
def test_a_damaged_data_file_is_one_line_naming_the_dataset_and_the_fix(dataset: Path, damage) -> None:
    data = dataset / "main_data.hdf5"
    data.write_bytes(damage(data.read_bytes()))
    with pytest.raises(UserError) as info:
        read_demonstrations("test/damaged-v0", observation_space=IMAGE, action_space=ACTIONS)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"Minari dataset 'test/damaged-v0' is damaged: its data in {dataset} cannot be read (")
    assert message.endswith("download or export it again (delete this copy first with `minari delete test/damaged-v0`)")
