"""Paired comparisons of two methods run on the same seeds.

For methods A and B, on the seeds both ran:

- ``difference``: A's success rate minus B's, with a 95% percentile bootstrap interval over seeds
  (``scipy.stats.bootstrap`` with ``paired=True``: a resample draws seeds, each with both of its
  outcomes), from a fixed generator so that the same rows always give the same interval;
- ``only_a`` / ``only_b``: the seeds where only A or only B succeeded, and ``p_value``, the exact
  McNemar test (two-sided binomial test of ``only_a`` among the discordant seeds);
- ``p_improvement``: the probability of improvement, the share of seeds where A's total reward is
  above B's, ties counting half (0.5: neither is better on a typical seed).

A says nothing better than B unless the interval of ``difference`` lies above 0.
"""

from __future__ import annotations

import functools
from typing import Any, Sequence

import numpy as np
from scipy import stats

#: Bootstrap resamples of the seeds, the interval's level and the resampling generator's seed.
RESAMPLES = 9999
LEVEL = 0.95
BOOTSTRAP_SEED = 0


def _mean_difference(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(a - b, axis=axis)


def _interval(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The percentile bootstrap interval of the mean paired difference ``a - b`` (one seed: the difference)."""
    if a.size == 1:  # one seed: nothing to resample
        return float(a[0] - b[0]), float(a[0] - b[0])
    interval = stats.bootstrap(
        (a, b),
        _mean_difference,
        paired=True,
        vectorized=True,
        n_resamples=RESAMPLES,
        confidence_level=LEVEL,
        method="percentile",
        rng=np.random.default_rng(BOOTSTRAP_SEED),
    ).confidence_interval
    return float(interval.low), float(interval.high)


def paired_difference(a: Sequence[float], b: Sequence[float]) -> dict[str, Any]:
    """The mean of ``a - b`` over the same seeds (one order) with its 95% bootstrap interval: for
    per-seed numbers that are not outcomes (an area under a curve)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    if x.shape != y.shape or x.ndim != 1 or x.size == 0:
        raise ValueError(f"a paired difference needs two sequences of one length >= 1, got {x.shape}, {y.shape}")
    low, high = _interval(x, y)
    return {"seeds": int(x.size), "difference": float(np.mean(x - y)), "ci_low": low, "ci_high": high}


def paired_comparison(
    success_a: Sequence[bool], success_b: Sequence[bool], reward_a: Sequence[float], reward_b: Sequence[float]
) -> dict[str, Any]:
    """A against B on the same seeds (the four sequences in one seed order); the fields of the
    module docstring and ``seeds``."""
    a, b = np.asarray(success_a, float), np.asarray(success_b, float)
    ra, rb = np.asarray(reward_a, float), np.asarray(reward_b, float)
    if not (a.shape == b.shape == ra.shape == rb.shape) or a.ndim != 1 or a.size == 0:
        raise ValueError(
            f"a paired comparison needs four sequences of one length >= 1, got shapes "
            f"{a.shape}, {b.shape}, {ra.shape}, {rb.shape}"
        )
    only_a, only_b = int(np.sum((a == 1) & (b == 0))), int(np.sum((a == 0) & (b == 1)))
    low, high = _interval(a, b)
    discordant = only_a + only_b
    return {
        "seeds": int(a.size),
        "difference": float(np.mean(a - b)),
        "ci_low": low,
        "ci_high": high,
        "only_a": only_a,
        "only_b": only_b,
        "p_value": float(stats.binomtest(only_a, discordant, 0.5).pvalue) if discordant else 1.0,
        "p_improvement": float(np.mean((ra > rb) + 0.5 * (ra == rb))),
    }


@functools.lru_cache(maxsize=None)
def smallest_shown_difference(seeds: int) -> float | None:
    """The smallest difference in success (a share) that :func:`verdict` can call better on ``seeds``
    paired seeds: k seeds solved by one method only and every other seed alike, for the least k
    whose interval lies above 0; None where not even every seed would show."""
    for k in range(1, seeds + 1):
        a = np.r_[np.ones(k), np.zeros(seeds - k)]
        if _interval(a, np.zeros(seeds))[0] > 0:
            return k / seeds
    return None


def verdict(comparison: dict[str, Any]) -> str:
    """``better``, ``worse`` or ``no difference shown``: where the interval of the difference lies."""
    if comparison["ci_low"] > 0:
        return "better"
    if comparison["ci_high"] < 0:
        return "worse"
    return "no difference shown"
