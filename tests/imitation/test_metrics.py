import math

import pytest

from metadagger.imitation.metrics import mean_interval, summarize, wilson_interval


def test_wilson_matches_known_values():
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3)
    assert hi == pytest.approx(0.9433, abs=1e-3)
    assert wilson_interval(0, 0) == (0.0, 1.0)


def test_mean_interval_is_the_normal_interval_of_the_mean():
    # mean 2, sample sd 1 (values 1, 2, 3), n 3: half-width 1.96 / sqrt(3)
    stat = mean_interval([1.0, 2.0, 3.0])
    assert stat["mean"] == 2.0 and stat["n"] == 3
    assert stat["high"] - stat["mean"] == pytest.approx(1.96 / math.sqrt(3)) and stat["mean"] - stat[
        "low"
    ] == pytest.approx(1.96 / math.sqrt(3))
    one = mean_interval([0.5])
    assert one["mean"] == 0.5 and math.isnan(one["low"]) and math.isnan(one["high"])
    with pytest.raises(ValueError):
        mean_interval([])


def test_summarize_counts_and_means():
    rows = [
        {"success": True, "reward": 800.0, "steps": 900, "expert_queries": 900},
        {"success": False, "reward": 200.0, "steps": 300, "expert_queries": 0},
    ]
    s = summarize(rows)
    assert s["successes"] == 1 and s["episodes"] == 2
    assert s["success_rate"] == 0.5
    assert s["mean_reward"] == 500.0 and s["mean_steps"] == 600.0
    assert s["expert_queries"] == 900


@pytest.mark.parametrize("n", range(1, 201))
def test_the_wilson_interval_holds_the_rate_at_none_and_all(n):
    for wins in (0, n):
        low, high = wilson_interval(wins, n)
        assert 0.0 <= low <= wins / n <= high <= 1.0
