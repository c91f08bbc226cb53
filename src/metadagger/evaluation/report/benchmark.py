"""The benchmark section of a report ("Success against expert queries"), built only from
``benchmark/summary.json``: every (method, setting) with its success interval and queries, the
paired comparisons of every method with the controls and the best gate, the
cheapest setting of each method that reaches 90% of DAgger's final success, and, where the
benchmark runs a MetaL DAgger method, what meta-training cost in expert queries against what MDM
saves per new seed where it succeeds as often as DAgger."""

from __future__ import annotations

import math
from typing import Any

from metadagger.evaluation.benchmark.coverage import rank_interval
from metadagger.evaluation.benchmark.coverage_figure import has_twins, plot_coverage
from metadagger.evaluation.benchmark.figure import plot_queries
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import MDI_METHODS, MDM_PREFIX, metal_family, reference_methods
from metadagger.evaluation.benchmark.summary import last_round, refit_check
from metadagger.evaluation.paired import smallest_shown_difference, verdict
from metadagger.evaluation.report.tables import figure_lines, markdown_table, pct
from metadagger.evaluation.rows import read_csv
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json

FIGURE = "queries.png"
#: The coverage figure's name in the report's figures.
COVERAGE_FIGURE = "coverage.png"
#: The share of DAgger's final success a method must reach to count as matching it.
MATCH_SHARE = 0.9


def benchmark_section(layout: RunLayout) -> list[str]:
    """Markdown lines of the benchmark section; [] if the run has no benchmark summary."""
    if not layout.benchmark_summary.is_file():
        return []
    summary = read_json(layout.benchmark_summary, "the benchmark summary")
    entries = summary["entries"]
    if not entries:
        return []
    seeds = max(e["seeds"] for e in entries)
    lines = [
        "## Success against expert queries",
        "",
        f"{seeds} unseen seeds. A query is one expert label of one state (the demonstration's steps included); "
        "every method starts from pi*'s trunk and the seed's BC head.",
        "",
    ]
    lines += figure_lines(
        layout.figures, FIGURE, "success against expert queries", lambda path: plot_queries(summary, path)
    ) + [""]
    ledger = all("mean_takeovers" in e for e in entries)
    cells = [
        (
            method_label(e["method"]),
            setting_cell(e),
            f"{pct(e['success_rate'])} ({e['successes']}/{e['seeds']}; "
            f"{pct(e['success_ci_low'])}-{pct(e['success_ci_high'])})",
            f"{e['mean_reward']:.1f}",
            f"{e['mean_queries']:.1f}",
            *((f"{e['mean_takeovers']:.1f}", f"{e['mean_episodes_asked']:.1f}") if ledger else ()),
        )
        for e in entries
    ]
    header = ("method", "setting", "success (95% Wilson interval)", "mean reward", "mean queries per seed")
    lines += markdown_table(header + (("takeovers per seed", "episodes asked per seed") if ledger else ()), cells)
    if ledger:
        lines += [
            "",
            "A takeover is a run of consecutive labelled steps in one episode (a context switch for the expert); "
            "an episode asked is one with at least one label; the demonstration is one of each. Every labelled "
            "state of every row, with the gate's score, is in `benchmark/labels.jsonl`.",
        ]
    return (
        lines
        + [""]
        + _paired(entries, summary.get("references", []), summary.get("comparisons", []))
        + _refits(layout)
        + _budgets(summary.get("budgets"))
        + _confirmation(layout)
        + _coverage(layout, summary.get("coverage"))
        + _matching(entries)
        + _amortisation(entries, summary["meta_training_queries"])
    )


def setting_cell(entry: dict[str, Any]) -> str:
    """An entry's setting, and its share of the demonstration where that is not all of it."""
    share = float(entry.get("demo_fraction", 1.0))
    setting = entry["setting"] or "-"
    if share == 1.0:
        return setting
    return f"{'' if setting == '-' else setting + ', '}{share:.0%} of the demonstration"


def _key(entry: dict[str, Any]) -> tuple[str, str, float]:
    """An entry's (or a reference's) method, setting and demonstration share."""
    return entry["method"], entry["setting"], float(entry.get("demo_fraction", 1.0))


def _against(comparison: dict[str, Any]) -> tuple[str, str, float]:
    """The :func:`_key` of the reference a comparison was made against."""
    return comparison["against"], comparison["against_setting"], float(comparison.get("against_demo_fraction", 1.0))


def _reference_label(entry: dict[str, Any]) -> str:
    setting = setting_cell(entry)
    return f"{method_label(entry['method'])}{f' {setting}' if setting != '-' else ''}"


def _paired(entries: list[dict[str, Any]], refs: list[dict[str, Any]], comparisons: list[dict[str, Any]]) -> list[str]:
    """Each method against each control and the best gate on the same seeds, and what they show."""
    if not refs or not comparisons:
        return []
    found = {(_key(c), _against(c)): c for c in comparisons}
    names = [_reference_label(r) for r in refs]
    cells = []
    for e in entries:
        row = [method_label(e["method"]), setting_cell(e)]
        for r in refs:
            c = found.get((_key(e), _key(r)))
            row.append(
                "-"
                if c is None
                else f"{_points(c['difference'])} ({_points(c['ci_low'])} to {_points(c['ci_high'])}); "
                f"{c['only_a']}:{c['only_b']}, p {c['p_value']:.2g}; PI {c['p_improvement']:.2f}"
            )
        cells.append(tuple(row))
    lines = [
        "### Paired comparisons with the controls and the best gate",
        "",
        "On the same seeds: the difference in success rate (points) with its 95% bootstrap interval over seeds; "
        "the seeds only this method : only the other solved, with the exact McNemar p; PI, the probability of "
        "improvement (the share of seeds with the higher reward, ties half). The best gate is the gated DAgger "
        "setting with the highest success here (chosen on these seeds, which favours it).",
        "",
    ]
    lines += markdown_table(("method", "setting", *(f"against {n}" for n in names)), cells) + [""]
    return lines + _conclusions(entries, refs, found, names) + [""]


def _refits(layout: RunLayout) -> list[str]:
    """BC refitted and DAgger after their last rounds against BC: does a refit keep what BC had?"""
    checks = refit_check(read_csv(layout.benchmark_table)) if layout.benchmark_table.is_file() else []
    if not checks:
        return []
    cells = [
        (
            f"{method_label(c['method'])} {c['setting']}",
            f"{_points(c['difference'])} ({_points(c['ci_low'])} to {_points(c['ci_high'])}); "
            f"{c['only_a']}:{c['only_b']}, p {c['p_value']:.2g}",
            "no: below BC" if verdict(c) == "worse" else "not shown below BC",
        )
        for c in checks
    ]
    return [
        "### Do the refits keep what BC had?",
        "",
        "Each refit after its last round against BC's own head on the same seeds (success difference in points, "
        "95% bootstrap interval; the seeds only it : only BC solved, McNemar p). A refit whose interval lies "
        "below 0 loses what BC had: then DAgger is no baseline, and its heads are poor targets for a mapper "
        '(docs/benchmark.md, "Refits that keep what BC had").',
        "",
        *markdown_table(("refit (rounds)", "against BC", "keeps what BC had"), cells),
        "",
    ]


def _points(value: float) -> str:
    return f"{100 * value:+.1f}"


def _conclusions(
    entries: list[dict[str, Any]], refs: list[dict[str, Any]], found: dict[tuple, dict[str, Any]], names: list[str]
) -> list[str]:
    """Which methods the paired intervals show better than every reference, and which not."""
    above_all = []
    for e in entries:
        if e["method"] in reference_methods():
            continue  # the oracle is a reference, never ranked
        cs = [found.get((_key(e), _key(r))) for r in refs]
        if all(c is not None and verdict(c) == "better" for c in cs):
            above_all.append(_reference_label(e))
    against = ", ".join(names)
    if above_all:
        return [f"Better than every one of {against} (paired 95% interval above 0): {', '.join(above_all)}."]
    return [
        f"No method is shown better than every one of {against}: no paired 95% interval lies above 0 against all of "
        "them."
    ]


def _curve_label(entry: dict[str, Any], side: str = "method") -> str:
    """A method read at budgets (``side`` ``method``), or the reference of a comparison (``against``)."""
    method = entry[side]
    share = float(entry["demo_fraction" if side == "method" else "against_demo_fraction"])
    label = method_label(method)
    return label if share == 1.0 else f"{label}, {share:.0%} of the demonstration"


def _floor(seeds: int) -> str:
    """What these seeds can show: the smallest difference a paired interval can put above 0."""
    floor = smallest_shown_difference(seeds)
    if floor is None:
        return f"On {seeds} seeds no paired interval can lie above 0."
    return (
        f"On {seeds} seeds a paired interval lies above 0 only from a difference of {100 * floor:.0f} points "
        "(that many seeds solved by one method only, the others alike): a smaller one cannot show here."
    )


def _budgets(reading: dict[str, Any] | None, where: str = "") -> list[str]:
    """Every method at equal budgets and by its area under the curve, and the best at each, paired;
    ``where`` names the seeds in the headings (the confirmation seeds')."""
    if not reading:
        return []
    budgets = reading["budgets"]
    auc = {(a["method"], float(a["demo_fraction"])): a for a in reading["auc"]}
    by_curve: dict[tuple[str, float], list[str]] = {}
    for b in budgets:
        for e in b["entries"]:
            by_curve.setdefault((e["method"], float(e["demo_fraction"])), []).append(
                f"{pct(e['success_rate'])} ({pct(e['success_ci_low'])}-{pct(e['success_ci_high'])})"
            )
    cells = [
        (_curve_label({"method": m, "demo_fraction": f}), *row, f"{auc[(m, f)]['mean']:.3f}")
        for (m, f), row in by_curve.items()
    ]
    header = (
        "method",
        *(f"success at demonstration + {b['share']:.0%} ({b['mean_budget']:.0f})" for b in budgets),
        "area under the curve",
    )
    lines = [
        f"### At equal budgets{where}",
        "",
        f"Every method read at the same spend on each of {len(reading['seeds'])} seeds: the demonstration's "
        "queries plus a share of plain DAgger's final queries beyond them on that seed (mean budget in "
        "brackets). A method is read at its last row within the budget (by queries), else at BC's outcome if "
        "the demonstration fits, else as a failure. The area under the curve is the mean of that success over "
        f"{reading['auc_points']} log-spaced budgets from the demonstration's queries to DAgger's final queries "
        f"(docs/benchmark.md, 'Equal budgets'). {_floor(len(reading['seeds']))}",
        "",
        *markdown_table(header, cells),
        "",
    ]
    for b in budgets:
        if b["best"] is None:
            continue
        best = _curve_label(b["best"])
        lines.append(f"- At {b['share']:.0%}: best {best}; " + _budget_comparisons(b["comparisons"]) + ".")
    if reading["best_auc"] is not None:
        parts = [
            f"{_curve_label(c, 'against')}: {c['difference']:+.3f} ({c['ci_low']:+.3f} to {c['ci_high']:+.3f})"
            for c in reading["auc_comparisons"]
        ]
        lines.append(
            f"- By the area under the curve: best {_curve_label(reading['best_auc'])}; against "
            + ("; ".join(parts) if parts else "nothing")
            + "."
        )
    return lines + [""] + _metal_twins(reading, where)


def _confirmation(layout: RunLayout) -> list[str]:
    """The equal-budget reading of the confirmation seeds (``benchmark.confirm_seeds``), if they ran."""
    confirm = layout.confirmation()
    if not confirm.benchmark_summary.is_file():
        return []
    reading = read_json(confirm.benchmark_summary, "the confirmation seeds' benchmark summary").get("budgets")
    if not reading:
        return []
    heading, blank, *rest = _budgets(reading, " (confirmation seeds)")
    intro = (
        f"The same methods on {len(reading['seeds'])} other unseen seeds (`benchmark.confirm_seeds`), fixed before "
        "any result was read, check what the seeds above chose (the best method and the best gate among them); "
        "their rows and summary are in `benchmark/confirm/`."
    )
    return [heading, blank, intro, "", *rest]


def _metal_twins(reading: dict[str, Any], where: str = "") -> list[str]:
    """Each method that reads a learned mapper's head against its constant twins, BC refitted and the
    best gate: the paired difference of success at each budget and of the area under the curve."""
    budgets = reading["budgets"]
    pairs: dict[tuple[str, float, str, float], list[str]] = {}
    for i, b in enumerate(budgets):  # the best gate may differ by budget: its row has a cell at its budgets only
        for c in b.get("metal", []):
            pairs.setdefault(_pair_key(c), ["-"] * len(budgets))[i] = (
                f"{_points(c['difference'])} ({_points(c['ci_low'])} to {_points(c['ci_high'])})"
            )
    auc = {
        _pair_key(c): f"{c['difference']:+.3f} ({c['ci_low']:+.3f} to {c['ci_high']:+.3f})"
        for c in reading.get("auc_metal", [])
    }
    for key in auc:  # the best gate by area may be best at no budget
        pairs.setdefault(key, ["-"] * len(budgets))
    if not pairs:
        return []
    header = (
        "method",
        "against",
        *(f"at demonstration + {b['share']:.0%}, points" for b in budgets),
        "area under the curve",
    )
    cells = [
        (
            _curve_label({"method": m, "demo_fraction": f}),
            _curve_label({"against": a, "against_demo_fraction": g}, "against"),
            *row,
            auc.get((m, f, a, g), "-"),
        )
        for (m, f, a, g), row in pairs.items()
    ]
    return [
        f"### MetaL DAgger against its constant twins{where}",
        "",
        "Each method that reads a learned mapper's head, paired on the same seeds with the same method reading a "
        "control's head (or zero) instead, with BC refitted and with the best gate, all at the same budgets: "
        "the difference in success (95% interval, points) and in the area under the curve.",
        "",
        *markdown_table(header, cells),
        "",
    ]


def _coverage(layout: RunLayout, coverage: dict[str, Any] | None) -> list[str]:
    """Whether the seeds' coverage gap predicts what a mapper adds over its constant twin: the figure
    and each comparison's rank correlation."""
    if not has_twins(coverage):
        return []
    assert coverage is not None
    cells = [
        (
            _curve_label(c),
            method_label(c["against"]),
            str(c["seeds"]),
            "-" if c["rho"] is None else f"{c['rho']:+.2f}",
            _rank_interval_cell(c),
            "-" if c["p_value"] is None else f"{c['p_value']:.3f}",
        )
        for c in coverage["methods"]
    ]
    gaps = coverage["gaps"]
    return [
        "### Coverage gap against the gain over the twin",
        "",
        f"A seed's coverage gap is the share of the energy of the states plain DAgger visited (centred at the "
        f"demonstration's mean) outside the principal directions holding {coverage['variance_share']:.0%} of the "
        f"demonstration's feature variance (docs/benchmark.md, 'Coverage'); here from {min(gaps):.3f} to "
        f"{max(gaps):.3f}, median {sorted(gaps)[len(gaps) // 2]:.3f}. A mapper can only add where the seed's "
        "own data says little: if it does, a larger gap goes with a larger gain in the area under the curve over "
        "the constant twin (Spearman's rho above 0).",
        "",
        *figure_lines(
            layout.figures,
            COVERAGE_FIGURE,
            "coverage gap against the gain over the constant twin",
            lambda path: plot_coverage(coverage, path),
        ),
        "",
        *markdown_table(("method", "against", "seeds", "Spearman's rho", "95% interval", "p-value"), cells),
        "",
    ]


def _rank_interval_cell(comparison: dict[str, Any]) -> str:
    """A rank correlation's 95% interval (Fisher's z), or - where there is none."""
    interval = rank_interval(comparison["rho"], comparison["seeds"])
    return "-" if interval is None else f"{interval[0]:+.2f} to {interval[1]:+.2f}"


def _pair_key(comparison: dict[str, Any]) -> tuple[str, float, str, float]:
    return (
        comparison["method"],
        float(comparison["demo_fraction"]),
        comparison["against"],
        float(comparison["against_demo_fraction"]),
    )


def _budget_comparisons(comparisons: list[dict[str, Any]]) -> str:
    if not comparisons:
        return "no reference to compare with"
    return "against " + "; ".join(
        f"{_curve_label(c, 'against')} {_points(c['difference'])} points "
        f"({_points(c['ci_low'])} to {_points(c['ci_high'])}), {verdict(c)}"
        for c in comparisons
    )


def _matching(entries: list[dict[str, Any]]) -> list[str]:
    """Each method's cheapest setting whose success reaches 90% of DAgger's final success."""
    final = last_round(entries)
    if final is None:
        return []
    if final["success_rate"] == 0:
        return [f"DAgger solves no seed after {final['setting']} rounds, so no method can be said to match it.", ""]
    target = MATCH_SHARE * final["success_rate"]
    cells = []
    for method in dict.fromkeys(e["method"] for e in entries):
        ok = sorted(
            (e for e in entries if e["method"] == method and e["success_rate"] >= target),
            key=lambda e: e["mean_queries"],
        )
        if ok:
            e = ok[0]
            cells.append((method_label(method), setting_cell(e), pct(e["success_rate"]), f"{e['mean_queries']:.1f}"))
        else:
            cells.append((method_label(method), "never", "-", "-"))
    return (
        [
            f"### Cheapest setting reaching {MATCH_SHARE:.0%} of DAgger's final success ({pct(final['success_rate'])} "
            "after "
            f"{final['setting']} rounds, {final['mean_queries']:.1f} queries per seed)",
            "",
        ]
        + markdown_table(("method", "setting", "success", "mean queries per seed"), cells)
        + [""]
    )


def _reads_meta_training(method: str) -> bool:
    """Whether ``method`` reads what meta-training made, the pairs or a mapper's head: MDM, the
    priors, the disagreement gate and MDI, their controls included."""
    return metal_family(method) is not None or method in MDI_METHODS


def _amortisation(entries: list[dict[str, Any]], meta: dict[str, int]) -> list[str]:
    """Queries spent on pi* and the pairs, and after how many new seeds each MDM method's saving
    against DAgger's final round repays them: only where the method succeeds, and at least as
    often as that round (a saving bought with lost successes repays nothing). [] for a benchmark
    without a MetaL DAgger method (gates alone, say): there is no meta-training to repay."""
    if not any(_reads_meta_training(e["method"]) for e in entries):
        return []
    final = last_round(entries)
    spent = int(meta.get("pistar", 0)) + int(meta.get("pairs", 0))
    lines = [
        "### Amortised cost of MetaL DAgger",
        "",
        f"Meta-training spent {spent} expert queries: {meta.get('pistar', 0)} on pi* and {meta.get('pairs', 0)} on "
        "the pairs.",
        "",
    ]
    mdm = [e for e in entries if e["method"].startswith(MDM_PREFIX)]
    if final is None or not mdm:
        return lines
    cells = []
    for e in mdm:
        saving = final["mean_queries"] - e["mean_queries"]
        cells.append(
            (_reference_label(e), pct(e["success_rate"]), f"{saving:.1f}", _repaid_after(e, final, saving, spent))
        )
    return (
        lines
        + [
            f"Against DAgger after {final['setting']} rounds ({pct(final['success_rate'])} success, "
            f"{final['mean_queries']:.1f} queries per seed). A method repays meta-training only if it succeeds, at "
            "least as often as DAgger, with fewer queries; otherwise its saving buys nothing and the last column "
            "says why:",
            "",
        ]
        + markdown_table(("method", "success", "queries saved per seed", "new seeds to repay meta-training"), cells)
        + [""]
    )


def _repaid_after(entry: dict[str, Any], final: dict[str, Any], saving: float, spent: int) -> str:
    """New seeds until ``saving`` per seed repays ``spent`` queries, or why it never does."""
    if entry["success_rate"] == 0:
        return "never (success 0%)"
    if entry["success_rate"] < final["success_rate"]:
        return f"never (success below DAgger's {pct(final['success_rate'])})"
    if saving <= 0:
        return "never (no queries saved)"
    return str(math.ceil(spent / saving))
