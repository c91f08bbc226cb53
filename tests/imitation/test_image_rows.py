from __future__ import annotations

import warnings

import numpy as np
import torch

from metadagger.imitation.data import Aggregate, Dataset
from metadagger.imitation.image_rows import ImageRows


def _parts(sizes, seed=0):
    rng = np.random.default_rng(seed)
    return [
        Dataset(obs=rng.integers(0, 256, (n, 5, 4, 3), dtype=np.uint8), labels=np.zeros(n, dtype=np.int64))
        for n in sizes
    ]


def test_rows_gathered_from_the_parts_are_the_concatenations_rows_in_order():
    parts = _parts([7, 1, 12, 4])
    whole = torch.from_numpy(np.concatenate([p.obs for p in parts]))
    rows = ImageRows(Aggregate(parts))
    assert len(rows) == 24
    for index in (
        torch.randperm(24, generator=torch.Generator().manual_seed(1))[:10],
        torch.arange(24),
        torch.tensor([23, 0, 7, 7]),
    ):
        batch = rows[index]
        assert batch.dtype == torch.uint8 and batch.is_contiguous() and torch.equal(batch, whole[index])
    assert torch.equal(rows.to("cpu"), whole)


def test_one_part_is_indexed_as_it_is_and_read_only_images_wrap_without_a_warning():
    (part,) = _parts([6])
    part.obs.flags.writeable = False  # as images loaded from a file may be
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rows = ImageRows(part)
    assert torch.equal(rows[torch.tensor([5, 0, 2])], torch.from_numpy(part.obs.copy())[[5, 0, 2]])
