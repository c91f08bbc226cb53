"""The coverage gap of a demonstration, its rank correlation with a method's gain, its figure."""

from __future__ import annotations

import pytest
import torch

from metadagger.evaluation.benchmark.coverage import coverage_gap, gap_against_gain
from metadagger.evaluation.benchmark.coverage_figure import drawn_comparisons, plot_coverage
from metadagger.evaluation.benchmark.summary import budget_reading, coverage_reading


def _plane(n: int, seed: int) -> torch.Tensor:
    """n points spread in the plane of the first two of 6 coordinates."""
    points = torch.zeros(n, 6)
    points[:, :2] = torch.randn(n, 2, generator=torch.Generator().manual_seed(seed))
    return points


def test_states_in_the_demonstrations_directions_have_no_gap_and_states_across_them_all_of_it():
    demo = _plane(50, 0)
    assert coverage_gap(demo, _plane(30, 1)) == pytest.approx(0.0, abs=1e-12)
    across = torch.zeros(30, 6)
    across[:, 4] = torch.randn(30, generator=torch.Generator().manual_seed(2))
    mean = demo.mean(dim=0)
    assert coverage_gap(demo, across + mean) == pytest.approx(1.0)
    # half the energy in the plane, half across it
    half = torch.zeros(2, 6)
    half[0, 0], half[1, 5] = 1.0, 1.0
    assert coverage_gap(demo, half + mean) == pytest.approx(0.5)
    assert coverage_gap(demo, mean.expand(4, 6)) == 0.0  # no energy about the demonstration's mean


def test_the_leading_directions_hold_the_chosen_share_of_the_variance():
    """A demonstration with 99% of its variance on one axis and 1% on another: at a share of 95% the
    second axis is outside, at 99.9% inside."""
    demo = torch.zeros(4, 3)
    demo[:, 0] = torch.tensor([-10.0, 10.0, -10.0, 10.0])
    demo[:, 1] = torch.tensor([-1.0, -1.0, 1.0, 1.0])
    visited = torch.tensor([[0.0, 1.0, 0.0]])
    assert coverage_gap(demo, visited, share=0.95) == pytest.approx(1.0)
    assert coverage_gap(demo, visited, share=0.999) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="features must be"):
        coverage_gap(demo, torch.zeros(2, 4))


def test_the_gap_against_the_gain_is_a_rank_correlation():
    assert gap_against_gain([0.1, 0.2, 0.3, 0.4], [0.0, 0.1, 0.5, 0.6])["rho"] == pytest.approx(1.0)
    assert gap_against_gain([0.1, 0.2, 0.3, 0.4], [0.6, 0.5, 0.1, 0.0])["rho"] == pytest.approx(-1.0)
    assert gap_against_gain([0.1, 0.2, 0.3], [0.0, 0.0, 0.0]) == {"seeds": 3, "rho": None, "p_value": None}


def _row(method: str, setting: str, seed: int, success: bool, queries: int, **extra) -> dict:
    return {
        "method": method,
        "setting": setting,
        "demo_fraction": 1.0,
        "seed": seed,
        "success": success,
        "reward": float(success),
        "expert_queries": queries,
        **extra,
    }


def test_the_reading_pairs_each_metal_method_with_its_twins_per_seed_and_the_figure_draws(tmp_path):
    """Seeds with a larger gap are the ones where the prior toward ridge succeeds and its twin fails."""
    rows = []
    for seed in range(6):
        gap = seed / 10
        rows += [
            _row("bc", "", seed, False, 100),
            _row("dagger", "1", seed, False, 300, coverage_gap=gap / 2),
            _row("dagger", "2", seed, True, 500, coverage_gap=gap),
            _row("prior-ridge", "", seed, seed >= 3, 100),
            _row("prior-mean-da", "", seed, False, 100),
            _row("prior-zero", "", seed, seed == 0, 100),
        ]
    coverage = coverage_reading(rows, budget_reading(rows))
    assert coverage["gaps"] == [s / 10 for s in range(6)]  # the last round's
    pairs = {(c["method"], c["against"]): c for c in coverage["methods"]}
    assert set(pairs) == {("prior-ridge", "prior-mean-da"), ("prior-ridge", "prior-zero")}
    assert pairs["prior-ridge", "prior-mean-da"]["gains"] == [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    assert pairs["prior-ridge", "prior-mean-da"]["rho"] > 0.8
    assert drawn_comparisons(coverage) == {"prior-": [pairs["prior-ridge", "prior-mean-da"]]}
    assert plot_coverage(coverage, tmp_path / "coverage.png").stat().st_size > 0
    assert coverage_reading([r for r in rows if "coverage_gap" not in r], budget_reading(rows)) is None
