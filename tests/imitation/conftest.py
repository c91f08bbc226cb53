"""Fixtures for the imitation tests: the toy corridor task (see toy_task.py)."""

from __future__ import annotations

import pytest
from toy_task import TOY_ARCH, CorridorTask

from metadagger.imitation.collect import collect
from metadagger.imitation.data import Dataset
from metadagger.policies import Policy, make_policy


@pytest.fixture(params=[True, False], ids=["discrete", "box"])
def task(request) -> CorridorTask:
    return CorridorTask(discrete=request.param)


@pytest.fixture
def discrete_task() -> CorridorTask:
    return CorridorTask(discrete=True)


@pytest.fixture
def policy(task) -> Policy:
    return make_policy(task, seed=0, **TOY_ARCH)


@pytest.fixture
def demo(task) -> Dataset:
    """One expert demonstration (seed 0) of ``task``."""
    return collect(task, [0], policy=None)[0].to_dataset()


@pytest.fixture
def discrete_demo(discrete_task) -> Dataset:
    """One expert demonstration (seed 0) of the discrete task."""
    return collect(discrete_task, [0], policy=None)[0].to_dataset()
