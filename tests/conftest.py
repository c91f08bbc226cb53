"""Shared fixtures: the command line's CPU kernels, pinned before numpy loads; one thread for torch
(CI has 2 cores); metadagger's Gymnasium ids registered (tests ``gym.make`` them directly;
importing metadagger does not register them); the machine's cache of finished artifacts off (a test
that reads it sets its own); a seeded generator and a closed port."""

from __future__ import annotations

import metadagger

metadagger.pin_cpu_kernels()  # before numpy, OpenCV and torch load, as the command line does

import os  # noqa: E402
import socket  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

from metadagger.tasks.gym_ids import register_envs  # noqa: E402

torch.set_num_threads(1)
register_envs()
os.environ["METADAGGER_CACHE"] = "off"  # every test trains its own pi*, its subprocesses too


@pytest.fixture(scope="session")
def carracing_ci_run(tmp_path_factory) -> Path:
    """A finished CarRacing ci run (pi*, 4 pairs, every mapper, 2 evaluation seeds, benchmark,
    report), made once per test session; copy it before changing it."""
    from metadagger.pipeline.stages import reproduce
    from metadagger.runfolder.driver import StageOptions

    run = tmp_path_factory.mktemp("carracing-ci") / "run"
    reproduce("carracing", "ci", run, options=StageOptions(workers=2, progress=False))
    return run


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    """A toy corridor run folder (one per test module) holding pi* and the pi*-head mapper: what
    the benchmark, the videos and a gate plug-in's tests start from."""
    from toy_task import CorridorTask

    from metadagger.imitation.bc import BCConfig
    from metadagger.mapping.mappers import Mapper
    from metadagger.metal_dagger.pistar import PiStarConfig, train_pistar
    from metadagger.policies import load_policy
    from metadagger.runfolder.layout import RunLayout

    pistar = PiStarConfig(
        seeds=(0, 1, 2, 3), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3)
    )
    layout = RunLayout(tmp_path_factory.mktemp("toy"))
    train_pistar(CorridorTask(), pistar, layout, progress=False)
    Mapper.pistar_head(load_policy(layout.pistar).head_vector()).save(layout.mapper("pistar-head"))
    return layout


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture
def closed_port() -> Iterator[int]:
    """A loopback port that refuses connections: bound (so nothing else takes it), not listening."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        yield sock.getsockname()[1]


@pytest.fixture
def silent_port() -> Iterator[int]:
    """A loopback port that accepts connections and never answers."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen(8)
        yield sock.getsockname()[1]
