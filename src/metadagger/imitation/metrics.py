"""Summary statistics: success rates with Wilson intervals, means with normal intervals."""

from __future__ import annotations

import math
from typing import Iterable, Mapping, Sequence


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval for a binomial proportion (95% for ``z=1.96``); it always holds
    ``successes / n`` and lies in [0, 1]."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # the interval holds p; at 0/n and n/n rounding can put a bound a hair beyond it
    return (min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half)))


def mean_interval(values: Sequence[float], z: float = 1.96) -> dict[str, float]:
    """The mean of ``values`` with its normal interval (95% for ``z=1.96``): mean ± z * sd / sqrt(n),
    the sd with Bessel's correction; ``low`` and ``high`` are NaN for fewer than two values."""
    n = len(values)
    if n == 0:
        raise ValueError("mean_interval needs at least one value")
    mean = math.fsum(values) / n
    half = z * math.sqrt(math.fsum((v - mean) ** 2 for v in values) / (n - 1) / n) if n > 1 else math.nan
    return {"mean": mean, "low": mean - half, "high": mean + half, "n": n}


def summarize(rows: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Success rate (with 95% Wilson interval), mean reward, mean steps and total expert queries
    of per-episode rows with keys ``success``, ``reward``, ``steps`` (and optionally ``expert_queries``)."""
    rows = list(rows)
    n = len(rows)
    wins = sum(bool(r["success"]) for r in rows)
    lo, hi = wilson_interval(wins, n)
    summary = {
        "episodes": n,
        "successes": wins,
        "success_rate": wins / n if n else 0.0,
        "success_ci_low": lo,
        "success_ci_high": hi,
        "mean_reward": sum(float(r["reward"]) for r in rows) / n if n else 0.0,
        "mean_steps": sum(float(r["steps"]) for r in rows) / n if n else 0.0,
    }
    if any("expert_queries" in r for r in rows):
        summary["expert_queries"] = int(sum(int(r.get("expert_queries", 0)) for r in rows))
    return summary
