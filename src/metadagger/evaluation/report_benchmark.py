"""The benchmark section of a report ("Success against expert queries"), built only from
``benchmark/summary.json``: every (method, setting) with its success interval and queries, the
cheapest setting of each method that reaches 90% of DAgger's final success, and what
meta-training cost in expert queries against what MDM saves per new seed."""

from __future__ import annotations

import math
from typing import Any

from metadagger.evaluation.benchmark import plot_queries
from metadagger.evaluation.methods import MDM_PREFIX
from metadagger.evaluation.tables import markdown_table, method_label, pct
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json

FIGURE = "queries.png"
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
    plot_queries(summary, layout.figures / FIGURE)
    seeds = max(e["seeds"] for e in entries)
    lines = ["## Success against expert queries", "",
             f"{seeds} unseen seeds. A query is one expert label of one state (the demonstration's steps included); "
             "every method starts from pi*'s trunk and the seed's BC head.", "",
             f"![success against expert queries](figures/{FIGURE})", ""]
    cells = [(method_label(e["method"]), e["setting"] or "-",
              f"{pct(e['success_rate'])} ({e['successes']}/{e['seeds']}; {pct(e['success_ci_low'])}-{pct(e['success_ci_high'])})",
              f"{e['mean_reward']:.1f}", f"{e['mean_queries']:.1f}") for e in entries]
    lines += markdown_table(("method", "setting", "success (95% Wilson interval)", "mean reward", "mean queries per seed"), cells)
    return lines + [""] + _matching(entries) + _amortisation(entries, summary["meta_training_queries"])


def _dagger_final(entries: list[dict[str, Any]]) -> dict[str, Any] | None:
    dagger = [e for e in entries if e["method"] == "dagger"]
    return max(dagger, key=lambda e: int(e["setting"])) if dagger else None


def _matching(entries: list[dict[str, Any]]) -> list[str]:
    """Each method's cheapest setting whose success reaches 90% of DAgger's final success."""
    final = _dagger_final(entries)
    if final is None:
        return []
    if final["success_rate"] == 0:
        return [f"DAgger solves no seed after {final['setting']} rounds, so no method can be said to match it.", ""]
    target = MATCH_SHARE * final["success_rate"]
    cells = []
    for method in dict.fromkeys(e["method"] for e in entries):
        ok = sorted((e for e in entries if e["method"] == method and e["success_rate"] >= target), key=lambda e: e["mean_queries"])
        if ok:
            e = ok[0]
            cells.append((method_label(method), e["setting"] or "-", pct(e["success_rate"]), f"{e['mean_queries']:.1f}"))
        else:
            cells.append((method_label(method), "never", "-", "-"))
    return ([f"### Cheapest setting reaching {MATCH_SHARE:.0%} of DAgger's final success ({pct(final['success_rate'])} after "
             f"{final['setting']} rounds, {final['mean_queries']:.1f} queries per seed)", ""]
            + markdown_table(("method", "setting", "success", "mean queries per seed"), cells) + [""])


def _amortisation(entries: list[dict[str, Any]], meta: dict[str, int]) -> list[str]:
    """Queries spent on pi* and the pairs, and after how many new seeds MDM's saving repays them."""
    final = _dagger_final(entries)
    spent = int(meta.get("pistar", 0)) + int(meta.get("pairs", 0))
    lines = ["### Amortised cost of MetaL DAgger", "",
             f"Meta-training spent {spent} expert queries: {meta.get('pistar', 0)} on pi* and {meta.get('pairs', 0)} on the pairs.", ""]
    mdm = [e for e in entries if e["method"].startswith(MDM_PREFIX)]
    if final is None or not mdm:
        return lines
    cells = []
    for e in mdm:
        saving = final["mean_queries"] - e["mean_queries"]
        seeds = math.ceil(spent / saving) if saving > 0 else None
        cells.append((method_label(e["method"]), pct(e["success_rate"]), f"{saving:.1f}", seeds if seeds is not None else "never"))
    return lines + [f"Against DAgger after {final['setting']} rounds ({pct(final['success_rate'])} success); a saving "
                    "buys nothing where the method's success is lower:", ""] + markdown_table(
        ("method", "success", "queries saved per seed", "new seeds to repay meta-training"), cells) + [""]
