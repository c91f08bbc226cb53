"""The MDI section of a report (paper Table 7 and Fig. 5), built only from ``eval/mdi.csv``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import MDI_METHODS
from metadagger.evaluation.report.tables import figure_lines, markdown_table, rate
from metadagger.evaluation.rows import read_csv
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.plotting import plt, save_figure

FIGURE = "mdi_cosine.png"
COSINE_KEYS = (("cosine_total", "accumulated"), ("cosine_per_action", "per action"))


def _by_method(rows: list[dict[str, Any]]) -> dict[str, dict[int, dict[str, Any]]]:
    """Rows by method (Table 7's three first, then the controls as they appear) and seed."""
    table: dict[str, dict[int, dict[str, Any]]] = {m: {} for m in MDI_METHODS}
    for r in rows:
        table.setdefault(r["method"], {})[r["seed"]] = r
    return table


def mdi_section(layout: RunLayout) -> list[str]:
    """Markdown lines of the MDI section (Table 7, expert queries, Fig. 5); [] if the run has no
    MDI table. Fig. 5 is drawn when the rows carry cosine distances (continuous-action tasks)."""
    path = layout.eval_table("mdi")
    if not path.is_file():
        return []
    table = _by_method(read_csv(path))
    methods = [m for m in table if table[m]]
    lines = [
        "## MDI: DAgger-MDI vs DAgger-BC vs DAgger on unseen seeds (Tables 6-7)",
        "",
        f"{len(table[methods[0]]) if methods else 0} unseen seeds. One-shot: solved by the head trained on the "
        "demonstration from the method's initialisation (Table 6 step 6). Two-shot: solved at step 6 or after "
        "one DAgger round (step 9).",
        "",
        "### Table 7: success rate (95% Wilson interval) and expert queries",
        "",
    ]
    cells = []
    for m in methods:
        rows = list(table[m].values())
        queries = sum(int(r["expert_queries"]) for r in rows) / len(rows)
        cells.append(
            (method_label(m), rate(rows, "one_shot_success"), rate(rows, "two_shot_success"), f"{queries:.1f}")
        )
    lines += markdown_table(("method", "one-shot", "two-shot", "mean expert queries per seed"), cells) + [""]
    if any(m not in MDI_METHODS for m in methods):
        lines += [
            "Controls (`mdi.controls`) run DAgger-MDI's steps with another initialiser: `mean-da` is the "
            "training pairs' mean w_DA, `pistar-head` pi*'s own head. Neither depends on the seed's w_BC; "
            "DAgger-MDI beating them is what shows the mapper learned something seed-specific.",
            "",
        ]
    return lines + _fig5(table, layout.figures)


def _measured(row: dict[str, Any]) -> bool:
    # read_csv leaves an empty cell (no distance: discrete actions) as ""
    return all(isinstance(row[k], (int, float)) and not isinstance(row[k], bool) for k, _ in COSINE_KEYS)


def _fig5(table: dict[str, dict[int, dict[str, Any]]], figures: Path) -> list[str]:
    """Fig. 5 (DAgger-MDI's cosine distances against each other method's, one point per seed) and
    how often DAgger-MDI is the closer one; [] if no distances are recorded."""
    mdi = table["dagger-mdi"]
    seeds = {
        m: [s for s in sorted(set(mdi) & set(table[m])) if _measured(mdi[s]) and _measured(table[m][s])]
        for m in MDI_METHODS[1:]
    }
    others = [m for m in MDI_METHODS[1:] if seeds[m]]
    if not others:
        return []
    lines = [
        "### Fig. 5: cosine distance to the expert in the final test (one point per seed)",
        "",
        "Below the diagonal: DAgger-MDI's actions are closer to the expert's than the other method's.",
        "",
        "| DAgger-MDI vs | seeds | DAgger-MDI lower: accumulated | DAgger-MDI lower: per action |",
        "|---|---|---|---|",
    ]
    for m in others:
        lower = [sum(float(mdi[s][key]) < float(table[m][s][key]) for s in seeds[m]) for key, _ in COSINE_KEYS]
        n = len(seeds[m])
        lines.append(f"| {method_label(m)} | {n} | {lower[0]}/{n} | {lower[1]}/{n} |")
    return (
        lines
        + [""]
        + figure_lines(figures, FIGURE, "MDI cosine distances", lambda path: _draw_fig5(table, seeds, others, path))
        + [""]
    )


def _draw_fig5(
    table: dict[str, dict[int, dict[str, Any]]], seeds: dict[str, list[int]], others: list[str], path: Path
) -> Path:
    """Fig. 5: per other method, DAgger-MDI's cosine distances against its own on each seed."""
    mdi = table["dagger-mdi"]
    fig, axes = plt.subplots(len(COSINE_KEYS), len(others), figsize=(3.8 * len(others), 6.4), squeeze=False)
    for col, m in enumerate(others):
        for row, (key, name) in enumerate(COSINE_KEYS):
            x = [float(table[m][s][key]) for s in seeds[m]]
            y = [float(mdi[s][key]) for s in seeds[m]]
            ax = axes[row][col]
            ax.scatter(x, y, s=14)
            hi = max(x + y) or 1.0  # distances are >= 0: the diagonal starts at 0
            ax.plot([0.0, hi], [0.0, hi], "k--", lw=0.8)
            ax.set_xlabel(f"{method_label(m)}: {name}")
            ax.set_ylabel(f"DAgger-MDI: {name}")
            if row == 0:
                ax.set_title(f"DAgger-MDI vs {method_label(m)}")
    fig.tight_layout()
    return save_figure(fig, path)
