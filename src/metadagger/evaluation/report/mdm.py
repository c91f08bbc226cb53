"""The MDM section of a report (paper Tables 1-2 and Fig. 4), built only from ``eval/mdm.csv``."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from metadagger.evaluation.benchmark.labels import method_label, method_order
from metadagger.evaluation.report.tables import by_method, figure_lines, markdown_table, rate
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.metrics import summarize
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.plotting import plt, save_figure

FIGURE = "mdm_vs_bc.png"


def mdm_section(layout: RunLayout) -> list[str]:
    """Table 1 (success, raw and adjusted for seeds BC solves), Table 2 (mean reward and steps with
    their spread, expert queries) and Fig. 4 (each method against BC per seed); [] if the run has
    no MDM table."""
    path = layout.eval_table("mdm")
    if not path.is_file():
        return []
    table = by_method(read_csv(path))
    bc = table.get("bc", {})
    bc_ok = {s for s, r in bc.items() if r["success"]}
    methods = method_order(table)
    lines = [
        "## Direct mapping (MDM) on unseen seeds",
        "",
        f"{len(bc)} unseen seeds; BC already succeeds on {len(bc_ok)} of them (left out of the adjusted rate).",
        "",
        "### Table 1: success rate (95% Wilson interval)",
        "",
    ]
    lines += markdown_table(
        ("method", "raw", "adjusted"),
        [
            (method_label(m), rate(table[m].values()), rate(r for s, r in table[m].items() if s not in bc_ok))
            for m in methods
        ],
    )
    lines += ["", "### Table 2: mean total reward and timesteps (± standard deviation over seeds)", ""]
    cells = []
    for m in methods:
        rows = list(table[m].values())
        s = summarize(rows)
        cells.append(
            (
                method_label(m),
                f"{s['mean_reward']:.1f} ± {_sd(rows, 'reward'):.1f}",
                f"{s['mean_steps']:.0f} ± {_sd(rows, 'steps'):.0f}",
                f"{s['expert_queries'] / max(s['episodes'], 1):.0f}",
            )
        )
    lines += markdown_table(("method", "mean reward", "mean timesteps", "expert queries per seed"), cells)
    lines += ["", "Every MDM method spends only the BC demonstration's expert queries; no DAgger round is run.", ""]
    for m in (m for m in methods if any(r.get("unlabelled_steps") not in (None, "") for r in table[m].values())):
        steps = [float(r["unlabelled_steps"]) for r in table[m].values()]
        lines += [
            f"{method_label(m)} also read the seed's context: one rollout of the BC head, never labelled, "
            f"{sum(steps) / len(steps):.0f} env steps per seed on average.",
            "",
        ]
    others = [m for m in methods if m != "bc"]
    if not others or "bc" not in table:
        return lines
    return (
        lines
        + ["### Fig. 4: each method against BC (one point per seed; filled: the method succeeded)", ""]
        + figure_lines(layout.figures, FIGURE, "MDM vs BC", lambda path: _scatter(table, others, path))
        + [""]
    )


def _sd(rows: list[dict[str, Any]], key: str) -> float:
    return statistics.stdev(float(r[key]) for r in rows) if len(rows) > 1 else 0.0


def _scatter(table: dict[str, dict[int, dict[str, Any]]], methods: list[str], path: Path) -> Path:
    """Draw Fig. 4: each of ``methods`` against BC, seed by seed."""
    fig, axes = plt.subplots(2, len(methods), figsize=(3.4 * len(methods), 6.6), squeeze=False, layout="constrained")
    for col, m in enumerate(methods):
        seeds = sorted(set(table[m]) & set(table["bc"]))
        ok = [table[m][s]["success"] for s in seeds]
        for row, key in enumerate(("reward", "steps")):
            ax = axes[row][col]
            x = [table["bc"][s][key] for s in seeds]
            y = [table[m][s][key] for s in seeds]
            ax.scatter([a for a, k in zip(x, ok) if k], [b for b, k in zip(y, ok) if k], s=16, label="success")
            ax.scatter(
                [a for a, k in zip(x, ok) if not k],
                [b for b, k in zip(y, ok) if not k],
                s=16,
                facecolors="none",
                edgecolors="C3",
                label="failure",
            )
            lo, hi = min(x + y, default=0), max(x + y, default=1)
            ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
            ax.set_xlabel(f"BC {key}")
            ax.set_ylabel(f"{key}")
            if row == 0:
                ax.set_title(method_label(m))
                if col == 0:
                    ax.legend(fontsize="small")
    return save_figure(fig, path)
