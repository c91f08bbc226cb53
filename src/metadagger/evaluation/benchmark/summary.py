"""The benchmark's summary: success by method and setting, paired comparisons with the references,
and every method read at equal budgets.

A method's own settings spend their own queries, so "better" at those settings mixes success with
spending. The budget reading (docs/benchmark.md, "Equal budgets") fixes the spend instead, per
seed: the demonstration's queries plus a share of plain DAgger's queries beyond them on that seed
(a share of DAgger's whole count would fall below the demonstration itself at small shares, where
every method but the zero-query controls reads as a failure):

- **Success at budget B**: the outcome of the method's last row (by queries, then table order)
  whose queries are at most B; with no row within B, BC's outcome at the demonstration's queries,
  or failure if even that exceeds B.
- **Area under the curve**: the mean success at budget over :data:`AUC_POINTS` log-spaced budgets
  from the demonstration's queries to plain DAgger's final queries; in [0, 1].

At each budget the best method (references aside) is named, with paired intervals against each
reference: the zero-query controls, BC refitted and the best gate at that budget. The oracle (the
learner's-mistakes rule) is a reference: tabled, never ranked. Each MetaL DAgger method that reads
a learned mapper's head (MDM, the priors, the disagreement gate) is also read against its constant
twins (the same method with a control's head, or zero, in the mapper's place:
:func:`~metadagger.evaluation.benchmark.methods.metal_twins`), BC refitted and the best gate, at each budget
and by the area under the curve.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from metadagger.evaluation.benchmark.coverage import VARIANCE_SHARE, gap_against_gain
from metadagger.evaluation.benchmark.methods import (
    BC_REFIT,
    DART,
    MDM_PREFIX,
    gated_methods,
    metal_twins,
    reference_methods,
)
from metadagger.evaluation.paired import paired_comparison, paired_difference
from metadagger.imitation.metrics import summarize, wilson_interval
from metadagger.mapping.registry import control_names

#: What a summary entry is keyed by: (method, setting, demonstration share).
Group = tuple[str, str, float]
#: The equal budgets: the demonstration's queries plus these shares of plain DAgger's final per-seed
#: queries beyond the demonstration.
BUDGET_SHARES = (0.05, 0.1, 0.25)
#: Budgets of the area under the success-against-queries curve, log-spaced.
AUC_POINTS = 16


def summarize_benchmark(rows: list[dict[str, Any]], meta_queries: dict[str, int]) -> dict[str, Any]:
    """Per (method, setting, demonstration share): success rate with its 95% Wilson interval, mean
    reward, mean queries, takeovers and episodes asked per seed (and the loss on the held-out
    expert states, where the rows have it: ``benchmark.held_out_every``); the queries spent on
    meta-training; the references (:func:`references`), every method's paired comparison with each
    (:func:`comparisons`), and the reading at equal budgets (:func:`budget_reading`)."""
    groups = _groups(rows)
    entries = []
    for (method, setting, fraction), group in groups.items():
        s = summarize(group)
        entries.append(
            {
                "method": method,
                "setting": setting,
                "demo_fraction": fraction,
                "seeds": s["episodes"],
                "successes": s["successes"],
                "success_rate": s["success_rate"],
                "success_ci_low": s["success_ci_low"],
                "success_ci_high": s["success_ci_high"],
                "mean_reward": s["mean_reward"],
                "mean_queries": s["expert_queries"] / s["episodes"],
                **{
                    f"mean_{name}": float(np.mean([r[name] for r in group]))
                    for name in ("takeovers", "episodes_asked", "expert_loss")
                    if all(name in r for r in group)
                },
            }
        )
    refs = references(entries)
    reading = budget_reading(rows)
    return {
        "entries": entries,
        "meta_training_queries": dict(meta_queries),
        "references": refs,
        "comparisons": comparisons(groups, refs),
        "budgets": reading,
        "coverage": coverage_reading(rows, reading),
    }


def _groups(rows: list[dict[str, Any]]) -> dict[Group, list[dict[str, Any]]]:
    groups: dict[Group, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], str(r["setting"]), float(r["demo_fraction"])), []).append(r)
    return groups


def refit_check(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Does a refit keep what BC had? BC refitted and DAgger, each after its last round, against BC,
    on the whole demonstration, paired on the seeds both ran (:func:`comparisons`); [] for a
    benchmark without BC or without either."""
    whole = {key: group for key, group in _groups(rows).items() if key[2] == 1.0}
    bc = next((key for key in whole if key[0] == "bc"), None)
    if bc is None:
        return []
    reference = [{"method": bc[0], "setting": bc[1], "demo_fraction": bc[2]}]
    out = []
    for method in (BC_REFIT, "dagger"):
        settings = [key for key in whole if key[0] == method]
        if settings:
            last = max(settings, key=lambda key: int(key[1]))
            out += comparisons({last: whole[last], bc: whole[bc]}, reference)
    return out


def _controls() -> set[str]:
    return {MDM_PREFIX + name for name in control_names()} | {BC_REFIT, DART}


def last_round(entries: list[dict[str, Any]], method: str = "dagger") -> dict[str, Any] | None:
    """``method``'s entry after its last round (DAgger's, or DART's at DAgger's last labels), of
    ``entries``, whose setting is the round (none: a method of one row, as BC); None where it did
    not run."""
    rows = [e for e in entries if e["method"] == method]
    return max(rows, key=lambda e: int(e["setting"] or 0)) if rows else None


def references(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What every method is compared with: each MDM control, BC refitted as DAgger (``bc-refit``),
    DART at DAgger's final labels (its last round), and the best gate (the gated DAgger setting with
    the highest success, the fewest queries on a tie; the oracle is a reference, not a gate), as
    ``method``/``setting``/``demo_fraction``."""
    controls, gated = _controls(), gated_methods()
    last_dart = last_round(entries, DART)
    refs = [e for e in entries if e["method"] in controls and (e["method"] != DART or e is last_dart)]
    gates = [e for e in entries if e["method"] in gated]
    if gates:
        refs.append(max(gates, key=lambda e: (e["success_rate"], -e["mean_queries"])))
    return [{"method": e["method"], "setting": e["setting"], "demo_fraction": e["demo_fraction"]} for e in refs]


def comparisons(groups: dict[Group, list[dict[str, Any]]], refs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every (method, setting, demonstration share) against every reference but itself, paired on
    the seeds both ran (:func:`metadagger.evaluation.paired.paired_comparison`)."""
    by_seed = {key: {r["seed"]: r for r in group} for key, group in groups.items()}
    out = []
    for ref in refs:
        against = (ref["method"], ref["setting"], ref["demo_fraction"])
        other = by_seed[against]
        for (method, setting, fraction), mine in by_seed.items():
            if (method, setting, fraction) == against:
                continue
            seeds = sorted(set(mine) & set(other))
            if not seeds:
                continue
            a, b = [mine[s] for s in seeds], [other[s] for s in seeds]
            stats = paired_comparison(
                [r["success"] for r in a], [r["success"] for r in b], [r["reward"] for r in a], [r["reward"] for r in b]
            )
            out.append(
                {
                    "method": method,
                    "setting": setting,
                    "demo_fraction": fraction,
                    "against": ref["method"],
                    "against_setting": ref["setting"],
                    "against_demo_fraction": ref["demo_fraction"],
                    **stats,
                }
            )
    return out


Curve = tuple[str, float]
"""A method read at budgets: (method, demonstration share); its rows on a seed are its settings."""


def success_at_budget(rows: Sequence[dict[str, Any]], fallback: dict[str, Any] | None, budget: float) -> dict[str, Any]:
    """The row a method is read at within ``budget`` queries on one seed: its last row (``rows`` in
    table order, sorted by queries) within it, else ``fallback`` (BC's row) within it, else a
    failure that spent nothing (``reward`` 0)."""
    within = [r for r in sorted(rows, key=lambda r: r["expert_queries"]) if r["expert_queries"] <= budget]
    if within:
        return within[-1]
    if fallback is not None and fallback["expert_queries"] <= budget:
        return fallback
    return {"success": False, "reward": 0.0, "expert_queries": 0}


def budget_reading(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Every method at the equal budgets :data:`BUDGET_SHARES` and by the area under its curve, per
    seed, with the best method at each and its paired comparisons; None without plain DAgger rows
    (budgets are shares of its queries) or BC rows (the demonstration's queries)."""
    final = _dagger_final(rows)
    start = {r["seed"]: r for r in rows if r["method"] == "bc" and float(r["demo_fraction"]) == 1.0}
    seeds = sorted(set(final) & set(start))
    if not seeds:
        return None
    curves: dict[Curve, dict[int, list[dict[str, Any]]]] = {}
    for r in rows:
        curves.setdefault((r["method"], float(r["demo_fraction"])), {}).setdefault(r["seed"], []).append(r)
    bc = {
        fraction: {r["seed"]: r for r in rows if r["method"] == "bc" and float(r["demo_fraction"]) == fraction}
        for fraction in {c[1] for c in curves}
    }

    def read(curve: Curve, seed: int, budget: float) -> dict[str, Any]:
        return success_at_budget(curves[curve].get(seed, []), bc[curve[1]].get(seed), budget)

    grid = {s: np.geomspace(max(start[s]["expert_queries"], 1), max(final[s], 1), AUC_POINTS) for s in seeds}
    ran = [c for c in curves if all(s in curves[c] for s in seeds)]
    auc = {c: [float(np.mean([read(c, s, b)["success"] for b in grid[s]])) for s in seeds] for c in ran}
    budget = {
        share: {s: start[s]["expert_queries"] + share * (final[s] - start[s]["expert_queries"]) for s in seeds}
        for share in BUDGET_SHARES
    }
    at: dict[float, dict[Curve, list[dict[str, Any]]]] = {
        share: {c: [read(c, s, budget[share][s]) for s in seeds] for c in ran} for share in BUDGET_SHARES
    }
    ranked = [c for c in ran if c[0] not in reference_methods() and c[0] not in _controls()]
    gated = gated_methods()
    budgets = []
    for share, read_at in at.items():
        table = [_budget_entry(c, outcomes) for c, outcomes in read_at.items()]
        best = max(ranked, key=lambda c: (_rate(read_at[c]), _auc_mean(auc[c])), default=None)
        gates = [c for c in ran if c[0] in gated]
        best_gate = max(gates, key=lambda c: (_rate(read_at[c]), _auc_mean(auc[c])), default=None)
        refs = [c for c in ran if c[0] in _controls()] + ([best_gate] if best_gate is not None else [])
        budgets.append(
            {
                "share": share,
                "mean_budget": float(np.mean(list(budget[share].values()))),
                "entries": table,
                "best": None if best is None else _curve_dict(best),
                "best_gate": None if best_gate is None else _curve_dict(best_gate),
                "comparisons": []
                if best is None
                else [
                    {**_curve_dict(best), **_against(ref), **_paired(read_at[best], read_at[ref])}
                    for ref in refs
                    if ref != best
                ],
                "metal": [
                    {**_curve_dict(c), **_against(ref), **_paired(read_at[c], read_at[ref])}
                    for c, ref in _metal_pairs(ran, best_gate)
                ],
            }
        )
    best_auc = max(ranked, key=lambda c: _auc_mean(auc[c]), default=None)
    best_gate_auc = max((c for c in ran if c[0] in gated), key=lambda c: _auc_mean(auc[c]), default=None)
    return {
        "seeds": seeds,
        "shares": list(BUDGET_SHARES),
        "auc_points": AUC_POINTS,
        "budgets": budgets,
        "auc": [{**_curve_dict(c), "mean": _auc_mean(auc[c]), "per_seed": auc[c]} for c in ran],
        "best_auc": None if best_auc is None else _curve_dict(best_auc),
        "auc_metal": [
            {**_curve_dict(c), **_against(ref), **paired_difference(auc[c], auc[ref])}
            for c, ref in _metal_pairs(ran, best_gate_auc)
        ],
        "auc_comparisons": []
        if best_auc is None
        else [
            {**_curve_dict(best_auc), **_against(ref), **paired_difference(auc[best_auc], auc[ref])}
            for ref in ran
            if ref != best_auc and (ref[0] in _controls() or ref[0] in gated or ref[0] in reference_methods())
        ],
    }


def _metal_pairs(ran: list[Curve], best_gate: Curve | None) -> list[tuple[Curve, Curve]]:
    """Each MetaL DAgger curve that reads a learned mapper (:func:`metal_twins`) with each of its
    references that ran: its constant twins, BC refitted, DART and ``best_gate``."""
    pairs = []
    for curve in ran:
        twins = metal_twins(curve[0])
        if not twins:
            continue
        refs = [(t, curve[1]) for t in twins] + [(BC_REFIT, 1.0), (DART, 1.0)]
        refs += [best_gate] if best_gate is not None else []
        pairs += [(curve, ref) for ref in refs if ref in ran and ref != curve]
    return pairs


def coverage_reading(rows: list[dict[str, Any]], reading: dict[str, Any] | None) -> dict[str, Any] | None:
    """Each seed's coverage gap (plain DAgger's last row's, :mod:`metadagger.evaluation.benchmark.coverage`),
    and for each MetaL DAgger curve and constant twin, the per-seed gain in the area under the
    curve and its rank correlation with the gap; None without gaps or a budget reading."""
    last = {seed: r for seed, r in last_rows(rows).items() if "coverage_gap" in r}
    if not last or reading is None:
        return None
    seeds = [s for s in reading["seeds"] if s in last]
    gaps = [float(last[s]["coverage_gap"]) for s in seeds]
    auc = {(a["method"], float(a["demo_fraction"])): dict(zip(reading["seeds"], a["per_seed"])) for a in reading["auc"]}
    methods = []
    for (method, fraction), mine in auc.items():
        for twin in metal_twins(method):
            other = auc.get((twin, fraction))
            if other is None:
                continue
            gains = [mine[s] - other[s] for s in seeds]
            methods.append(
                {**_curve_dict((method, fraction)), "against": twin, **gap_against_gain(gaps, gains), "gains": gains}
            )
    return {"variance_share": VARIANCE_SHARE, "seeds": seeds, "gaps": gaps, "methods": methods}


def last_rows(rows: list[dict[str, Any]], method: str = "dagger") -> dict[int, dict[str, Any]]:
    """``method``'s row after its last round, per seed (the rows' twin of :func:`last_round`; a
    method of one row, as BC, gives that row)."""
    last: dict[int, dict[str, Any]] = {}
    for r in rows:
        if r["method"] == method and (
            r["seed"] not in last or int(r["setting"] or 0) > int(last[r["seed"]]["setting"] or 0)
        ):
            last[r["seed"]] = r
    return last


def _dagger_final(rows: list[dict[str, Any]]) -> dict[int, int]:
    """Plain DAgger's queries after its last round, per seed."""
    return {seed: int(r["expert_queries"]) for seed, r in last_rows(rows).items()}


def _rate(outcomes: list[dict[str, Any]]) -> float:
    return float(np.mean([bool(o["success"]) for o in outcomes]))


def _auc_mean(values: list[float]) -> float:
    return float(np.mean(values))


def _curve_dict(curve: Curve) -> dict[str, Any]:
    """A curve as ``method``/``demo_fraction`` fields."""
    return {"method": curve[0], "demo_fraction": curve[1]}


def _against(curve: Curve) -> dict[str, Any]:
    """A reference curve as ``against``/``against_demo_fraction`` fields."""
    return {"against": curve[0], "against_demo_fraction": curve[1]}


def _budget_entry(curve: Curve, outcomes: list[dict[str, Any]]) -> dict[str, Any]:
    wins = sum(bool(o["success"]) for o in outcomes)
    low, high = wilson_interval(wins, len(outcomes))
    return {
        "method": curve[0],
        "demo_fraction": curve[1],
        "seeds": len(outcomes),
        "successes": wins,
        "success_rate": wins / len(outcomes),
        "success_ci_low": low,
        "success_ci_high": high,
        "mean_queries": float(np.mean([o["expert_queries"] for o in outcomes])),
    }


def _paired(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, Any]:
    return paired_comparison(
        [o["success"] for o in a], [o["success"] for o in b], [o["reward"] for o in a], [o["reward"] for o in b]
    )
