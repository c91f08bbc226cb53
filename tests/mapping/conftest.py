"""Fixtures of the mapping tests: one synthetic split and a pi* head, shared by the session."""

from __future__ import annotations

import numpy as np
import pytest
from mapping_data import synthetic_split

from metadagger.metal_dagger.store import PairSplit


@pytest.fixture(scope="session")
def split() -> PairSplit:
    return synthetic_split()


@pytest.fixture(scope="session")
def pistar_head(split: PairSplit) -> np.ndarray:
    return split.w_da_train[0].numpy() + 0.5
