"""Cosine early stop (paper section 3.4.2)."""

from __future__ import annotations

import numpy as np
import pytest

from metadagger.imitation.early_stop import DEFAULT_THRESHOLD, MIN_LABEL_NORM, CosineEarlyStop, cosine_distance


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ([1, 0, 0], [2, 0, 0], 0.0),
        ([1, 0, 0], [0, 3, 0], 1.0),
        ([1, 1, 0], [-1, -1, 0], 2.0),
        ([1, 0, 0], [1, 1, 0], 1 - 1 / np.sqrt(2)),
        ([0, 0, 0], [0, 0, 0], 0.0),
        ([0, 0, 0], [0, 1, 0], 1.0),
        ([0.5, 0, 0], [0, 0, 0], 1.0),
    ],
)
def test_cosine_distance(a, b, expected):
    assert cosine_distance(np.array(a, float), np.array(b, float)) == pytest.approx(expected)


def test_cosine_distance_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="same shape"):
        cosine_distance(np.zeros(3), np.zeros(4))


def test_accumulates_and_stops_past_the_threshold():
    stop = CosineEarlyStop(threshold=2.5, min_label_norm=0.0)
    label = np.array([1.0, 0.0, 0.0])
    assert stop.update(label, label) is False  # 0
    assert stop.update(np.array([0.0, 1.0, 0.0]), label) is False  # 1
    assert stop.update(np.array([-1.0, 0.0, 0.0]), label) is True  # 3 > 2.5
    assert stop.update(label, label) is True  # stays stopped
    assert stop.total == pytest.approx(3.0)
    assert stop.distances == pytest.approx([0.0, 1.0, 2.0, 0.0])
    assert stop.steps == 4 and stop.mean == pytest.approx(0.75)
    stop.reset()
    assert stop.total == 0.0 and stop.mean == 0.0 and stop.steps == 0 and not stop.stopped


def test_equal_threshold_does_not_stop():
    stop = CosineEarlyStop(threshold=1.0, min_label_norm=0.0)
    assert stop.update(np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])) is False


def test_short_expert_labels_do_not_count():
    stop = CosineEarlyStop(threshold=1.0, min_label_norm=0.1)
    assert stop.update(np.array([-1.0, 0.0, 0.0]), np.array([0.05, 0.0, 0.0])) is False
    assert stop.distances == [0.0]
    # the learner standing still while the expert wants to move counts as orthogonal
    stop.update(np.zeros(3), np.array([0.5, 0.0, 0.0]))
    assert stop.total == pytest.approx(1.0)


def test_defaults_and_validation():
    stop = CosineEarlyStop()
    assert stop.threshold == DEFAULT_THRESHOLD and stop.min_label_norm == MIN_LABEL_NORM
    with pytest.raises(ValueError, match="threshold"):
        CosineEarlyStop(threshold=0.0)
    with pytest.raises(ValueError, match="threshold"):
        CosineEarlyStop(threshold=float("nan"))
    with pytest.raises(ValueError, match="min_label_norm"):
        CosineEarlyStop(threshold=1.0, min_label_norm=-1.0)


@pytest.mark.parametrize("value", [0.0, -1.0, float("inf"), float("nan"), "40"])
def test_config_thresholds_name_the_field(value):
    from metadagger.errors import UserError
    from metadagger.imitation.early_stop import check_threshold
    from metadagger.metal_dagger.pairs import PairConfig

    check_threshold("pairs.early_stop", None)
    check_threshold("pairs.early_stop", 40.0)
    with pytest.raises(UserError, match=r"^pairs\.early_stop must be a finite number > 0 or null"):
        PairConfig(early_stop=value)
