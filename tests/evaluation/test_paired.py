"""Paired comparisons of methods on the same seeds, and the benchmark summary's references."""

from __future__ import annotations

import pytest

from metadagger.evaluation.benchmark.protocol import summarize_benchmark
from metadagger.evaluation.paired import paired_comparison, smallest_shown_difference, verdict


def test_counts_difference_exact_test_and_probability_of_improvement():
    c = paired_comparison([1, 1, 0, 1, 1], [0, 1, 0, 1, 0], [5.0, 2.0, 1.0, 3.0, 9.0], [1.0, 2.0, 0.0, 4.0, 1.0])
    assert (c["seeds"], c["only_a"], c["only_b"]) == (5, 2, 0)
    assert c["difference"] == pytest.approx(0.4)
    assert c["p_value"] == pytest.approx(0.5)  # both discordant seeds for A: 2 * 0.5**2
    assert c["p_improvement"] == pytest.approx((3 + 0.5) / 5)  # A's reward higher on 3 seeds, a tie on one
    assert c["ci_low"] <= c["difference"] <= c["ci_high"]
    assert c == paired_comparison(
        [1, 1, 0, 1, 1], [0, 1, 0, 1, 0], [5.0, 2.0, 1.0, 3.0, 9.0], [1.0, 2.0, 0.0, 4.0, 1.0]
    )


def test_the_interval_decides_the_verdict():
    n = 30
    better = paired_comparison([1] * n, [0] * 10 + [1] * 20, [1.0] * n, [0.0] * n)
    assert better["ci_low"] > 0 and verdict(better) == "better" and better["p_value"] < 0.01
    worse = paired_comparison([0] * 10 + [1] * 20, [1] * n, [0.0] * n, [1.0] * n)
    assert worse["ci_high"] < 0 and verdict(worse) == "worse"
    same = paired_comparison([1, 0] * 10, [1, 0] * 10, [1.0] * 20, [1.0] * 20)
    assert (same["ci_low"], same["ci_high"], same["p_value"], same["p_improvement"]) == (0.0, 0.0, 1.0, 0.5)
    assert verdict(same) == "no difference shown"
    mixed = paired_comparison([1, 0] * 5, [0, 1] * 5, [0.0] * 10, [0.0] * 10)
    assert mixed["ci_low"] < 0 < mixed["ci_high"] and verdict(mixed) == "no difference shown"


def test_one_seed_and_bad_shapes():
    one = paired_comparison([True], [False], [1.0], [0.0])
    assert (one["difference"], one["ci_low"], one["ci_high"]) == (1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="one length"):
        paired_comparison([1, 0], [1], [0.0, 0.0], [0.0])
    with pytest.raises(ValueError, match="one length"):
        paired_comparison([], [], [], [])


def _rows(method: str, setting: str, successes: list[int], queries: int) -> list[dict]:
    return [
        {
            "method": method,
            "setting": setting,
            "demo_fraction": 1.0,
            "seed": seed,
            "success": bool(ok),
            "reward": float(ok),
            "steps": 10,
            "expert_queries": queries,
        }
        for seed, ok in enumerate(successes)
    ]


def test_the_summary_compares_every_method_with_each_control_and_the_best_gate():
    rows = (
        _rows("bc", "", [0, 0, 1, 0], 10)
        + _rows("mdm-dm", "", [1, 1, 1, 0], 10)
        + _rows("mdm-mean-da", "", [1, 0, 1, 0], 10)
        + _rows("mdm-pistar-head", "", [0, 1, 1, 0], 10)
        + _rows("dagger-random", "0.5", [1, 1, 1, 1], 40)
        + _rows("dagger-random", "0.05", [1, 1, 1, 1], 15)
        + _rows("dagger-novelty", "0.5", [1, 1, 0, 1], 12)
    )
    summary = summarize_benchmark(rows, {"pistar": 1, "pairs": 2})
    # the best gate: the highest success, then the fewest queries
    assert summary["references"] == [
        {"method": "mdm-mean-da", "setting": "", "demo_fraction": 1.0},
        {"method": "mdm-pistar-head", "setting": "", "demo_fraction": 1.0},
        {"method": "dagger-random", "setting": "0.05", "demo_fraction": 1.0},
    ]
    pairs = {(c["method"], c["setting"], c["against"], c["against_setting"]): c for c in summary["comparisons"]}
    assert len(pairs) == 3 * 7 - 3  # every entry against every reference but itself
    assert ("mdm-mean-da", "", "mdm-mean-da", "") not in pairs
    dm = pairs[("mdm-dm", "", "mdm-mean-da", "")]
    assert (dm["only_a"], dm["only_b"], dm["difference"]) == (1, 0, 0.25)
    assert pairs[("bc", "", "dagger-random", "0.05")]["difference"] == -0.75


@pytest.mark.parametrize("seeds", [5, 20, 50])
def test_the_smallest_shown_difference_is_the_least_one_way_discordance_the_verdict_calls_better(seeds):
    floor = smallest_shown_difference(seeds)
    k = round(floor * seeds)

    def one_way(solved: int) -> dict:
        a = [True] * solved + [False] * (seeds - solved)
        return paired_comparison(a, [False] * seeds, [1.0] * seeds, [0.0] * seeds)

    assert verdict(one_way(k)) == "better" and verdict(one_way(k - 1)) == "no difference shown"
    assert smallest_shown_difference(40) == pytest.approx(0.1)  # the seeds a 10-point difference needs at the least
