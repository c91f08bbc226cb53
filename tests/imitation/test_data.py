"""Dataset: validation, concatenation, empty; Aggregate: appending without copying."""

from __future__ import annotations

import numpy as np
import pytest

from metadagger.imitation.data import Aggregate, Dataset


def make(n: int, *, discrete: bool = True) -> Dataset:
    labels = np.arange(n, dtype=np.int64) if discrete else np.zeros((n, 3), np.float32)
    return Dataset(obs=np.zeros((n, 4, 4, 3), np.uint8), labels=labels)


def test_concat_appends_rows_in_order():
    a, b = make(2), make(3)
    both = a.concat(b)
    assert len(both) == 5 and both.discrete
    np.testing.assert_array_equal(both.labels, [0, 1, 0, 1, 2])


def test_empty_keeps_shapes():
    like = make(4, discrete=False)
    empty = Dataset.empty(like)
    assert len(empty) == 0 and empty.obs.shape[1:] == (4, 4, 3) and empty.labels.shape == (0, 3)
    assert len(empty.concat(like)) == 4 and not empty.discrete


def test_mismatched_lengths_name_both_numbers():
    with pytest.raises(ValueError, match="obs has 3 rows but labels has 2"):
        Dataset(obs=np.zeros((3, 4, 4, 3), np.uint8), labels=np.zeros(2, np.int64))


@pytest.mark.parametrize(
    "obs,labels,match",
    [
        (np.zeros((2, 4, 4, 3), np.float32), np.zeros(2, np.int64), "obs must be a uint8"),
        (np.zeros((2, 4, 4), np.uint8), np.zeros(2, np.int64), "obs must be a uint8"),
        (np.zeros((2, 4, 4, 3), np.uint8), np.zeros(2, np.int32), "labels must be int64"),
        (np.zeros((2, 4, 4, 3), np.uint8), np.zeros(2, np.float32), "labels must be int64"),
    ],
)
def test_bad_dtypes_or_shapes(obs, labels, match):
    with pytest.raises(ValueError, match=match):
        Dataset(obs=obs, labels=labels)


def test_concat_rejects_other_label_kind():
    with pytest.raises(ValueError, match="cannot concatenate"):
        make(2).concat(make(2, discrete=False))


def test_aggregate_keeps_parts_and_concatenates_on_demand():
    a, b, c = make(2), make(3), make(1)
    aggregate = Aggregate([a]).append(b, Aggregate([c]))
    assert aggregate.parts == (a, b, c)  # nested aggregates are flattened, no image copied
    assert len(aggregate) == 6 and aggregate.discrete and aggregate.image_shape == (4, 4, 3)
    np.testing.assert_array_equal(aggregate.labels, [0, 1, 0, 1, 2, 0])
    np.testing.assert_array_equal(aggregate.obs, a.concat(b, c).obs)
    assert Aggregate([a]).obs is a.obs


def test_aggregate_rejects_other_label_kind_and_no_parts():
    with pytest.raises(ValueError, match="cannot concatenate"):
        Aggregate([make(2)]).append(make(2, discrete=False))
    with pytest.raises(ValueError, match="at least one dataset"):
        Aggregate([])
