"""``report/report.md`` and its figures, built only from a run's CSV/JSON artifacts.

Sections appear for the stages a run has finished: pi*, pairs, mapper learning curves (Fig. 8),
MDM (Tables 1-2, Fig. 4, expert queries), one-shot (Tables 3-5) and, for runs with
``eval/mdi.csv`` (Fetch), the MDI protocol (Table 7, Fig. 5; :mod:`~metadagger.evaluation.report_fetch`).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from metadagger.imitation.metrics import summarize
from metadagger.evaluation.report_fetch import mdi_section
from metadagger.evaluation.rows import read_csv
from metadagger.io import write_text
from metadagger.evaluation.curves import plot_curves
from metadagger.plotting import plt, save_figure

METHOD_ORDER = ("bc", "dm", "sam", "tam", "mean-da", "pistar-head")
LABELS = {"bc": "BC", "dm": "DM", "sam": "SAM", "tam": "TAM", "mean-da": "mean-DA (control)", "pistar-head": "pi*-head (control)"}


def build_report(run: str | Path) -> Path:
    """Write ``<run>/report/report.md`` (+ ``figures/``) from the run's artifacts; return its path."""
    run = Path(run)
    out = run / "report"
    figures = out / "figures"
    parts = [f"# MetaL DAgger report: `{run.name}`", ""]
    parts += _groundtruth_section(run)
    parts += _pairs_section(run)
    parts += _curves_section(run, figures)
    mdm = run / "eval" / "mdm.csv"
    if mdm.is_file():
        rows = read_csv(mdm)
        parts += _mdm_section(rows, figures)
        oneshot = run / "eval" / "oneshot.csv"
        if oneshot.is_file():
            parts += _oneshot_section(rows, read_csv(oneshot))
    parts += mdi_section(run, figures)
    return write_text(out / "report.md", "\n".join(parts) + "\n")


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def _groundtruth_section(run: Path) -> list[str]:
    path = run / "groundtruth" / "metrics.json"
    if not path.is_file():
        return []
    m = json.loads(path.read_text())
    lines = ["## Ground-truth policy pi*", "", "| seeds | successes | success | 95% CI | mean reward | mean steps |", "|---|---|---|---|---|---|"]
    for key, name in (("own_seeds", "its own (training) seeds"), ("unseen_seeds", "unseen seeds")):
        s = m[key]
        lines.append(f"| {name} | {s['successes']}/{s['episodes']} | {_pct(s['success_rate'])} | "
                     f"{_pct(s['success_ci_low'])}-{_pct(s['success_ci_high'])} | {s['mean_reward']:.1f} | {s['mean_steps']:.0f} |")
    lines += ["", f"Expert queries spent on pi*: {m.get('expert_queries', 0)}.", ""]
    return lines


def _pairs_section(run: Path) -> list[str]:
    path = run / "pairs" / "summary.json"
    if not path.is_file():
        return []
    s = json.loads(path.read_text())
    lines = ["## Pairs (w_BC, w_DA)", "", f"{s['seeds']} seeds, {s['kept']} pairs kept.", "",
             "| outcome | seeds | share |", "|---|---|---|"]
    for name, count in s["outcomes"].items():
        lines.append(f"| {name.replace('_', ' ').replace('/', ', ')} | {count} | {_pct(s['shares'][name])} |")
    return lines + [""]


def _curves_section(run: Path, figures: Path) -> list[str]:
    lines = []
    for kind in ("dm", "sam", "tam"):
        csv_path = run / "mappers" / kind / "curves.csv"
        if csv_path.is_file():
            plot_curves(csv_path, figures / f"curves_{kind}.png")
            lines += [f"![{kind.upper()} learning curves](figures/curves_{kind}.png)", ""]
    return ["## Mapper learning curves (Fig. 8)", "", *lines] if lines else []


def _by_method(rows: list[dict[str, Any]]) -> dict[str, dict[int, dict[str, Any]]]:
    table: dict[str, dict[int, dict[str, Any]]] = defaultdict(dict)
    for r in rows:
        table[r["method"]][r["seed"]] = r
    return table


def _mdm_section(rows: list[dict[str, Any]], figures: Path) -> list[str]:
    table = _by_method(rows)
    bc = table.get("bc", {})
    bc_ok = {s for s, r in bc.items() if r["success"]}
    methods = [m for m in METHOD_ORDER if m in table]
    n = len(bc)
    lines = ["## Direct mapping (MDM) on unseen seeds", "",
             f"{n} unseen seeds; BC already succeeds on {len(bc_ok)} of them (left out of the adjusted rate).", "",
             "### Table 1: success rate (95% Wilson interval)", "",
             "| method | raw | adjusted |", "|---|---|---|"]
    for m in methods:
        raw = summarize(table[m].values())
        adj = summarize(r for s, r in table[m].items() if s not in bc_ok)
        lines.append(f"| {LABELS[m]} | {_pct(raw['success_rate'])} ({raw['successes']}/{raw['episodes']}; "
                     f"{_pct(raw['success_ci_low'])}-{_pct(raw['success_ci_high'])}) | "
                     f"{_pct(adj['success_rate'])} ({adj['successes']}/{adj['episodes']}; "
                     f"{_pct(adj['success_ci_low'])}-{_pct(adj['success_ci_high'])}) |")
    lines += ["", "### Table 2: mean total reward and timesteps", "",
              "| method | mean reward | mean timesteps | expert queries per seed |", "|---|---|---|---|"]
    for m in methods:
        s = summarize(table[m].values())
        lines.append(f"| {LABELS[m]} | {s['mean_reward']:.1f} | {s['mean_steps']:.0f} | {s['expert_queries'] / max(s['episodes'], 1):.0f} |")
    lines += ["", "Every MDM method spends only the BC demonstration's expert queries; no DAgger round is run.", ""]
    _scatter(table, [m for m in methods if m != "bc"], figures / "mdm_vs_bc.png")
    return lines + ["### Fig. 4: each method against BC (one point per seed)", "", "![MDM vs BC](figures/mdm_vs_bc.png)", ""]


def _scatter(table: dict[str, dict[int, dict[str, Any]]], methods: list[str], path: Path) -> None:
    if not methods:
        return
    fig, axes = plt.subplots(2, len(methods), figsize=(3.2 * len(methods), 6.2), squeeze=False)
    for col, m in enumerate(methods):
        seeds = sorted(set(table[m]) & set(table["bc"]))
        for row, key in enumerate(("reward", "steps")):
            ax = axes[row][col]
            x = [table["bc"][s][key] for s in seeds]
            y = [table[m][s][key] for s in seeds]
            ax.scatter(x, y, s=14)
            lo, hi = min(x + y, default=0), max(x + y, default=1)
            ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
            ax.set_xlabel(f"BC {key}")
            ax.set_ylabel(f"{LABELS[m]} {key}")
            if row == 0:
                ax.set_title(LABELS[m])
    save_figure(fig, path)


def _oneshot_section(mdm_rows: list[dict[str, Any]], oneshot_rows: list[dict[str, Any]]) -> list[str]:
    mdm = _by_method(mdm_rows)
    shots = _by_method(oneshot_rows)
    lines = ["## One-shot learning with the mapper as initialiser (Tables 3-5)", ""]
    for method in ("sam", "dm", "tam", "mean-da", "pistar-head"):
        rows = shots.get(f"oneshot-{method}", {})
        if method not in mdm:
            continue
        wins = sum(r["success"] for r in rows.values())
        lines += [f"### {LABELS[method]}: {wins}/{len(rows)} failed seeds solved by one-shot", "",
                  "| seed | BC reward | BC steps | mapped reward | mapped steps | one-shot reward | one-shot steps | success |",
                  "|---|---|---|---|---|---|---|---|"]
        for seed in sorted(rows):
            b, m, o = mdm["bc"][seed], mdm[method][seed], rows[seed]
            lines.append(f"| {seed} | {b['reward']:.1f} | {b['steps']} | {m['reward']:.1f} | {m['steps']} | "
                         f"{o['reward']:.1f} | {o['steps']} | {'yes' if o['success'] else 'no'} |")
        lines.append("")
    return lines
