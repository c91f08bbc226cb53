"""The one-shot section of a report (paper Tables 3-5), built only from ``eval/mdm.csv`` and
``eval/oneshot.csv``: for every seed a mapper failed on, its head refitted once on the demonstration."""

from __future__ import annotations

from metadagger.evaluation.benchmark.labels import method_label, method_order
from metadagger.evaluation.mdm import ONESHOT_PREFIX
from metadagger.evaluation.report.tables import by_method, markdown_table
from metadagger.evaluation.rows import read_csv
from metadagger.runfolder.layout import RunLayout


def oneshot_section(layout: RunLayout) -> list[str]:
    """One table per mapper: BC, the mapped head and its one-shot refit on each failed seed."""
    mdm_path, shots_path = layout.eval_table("mdm"), layout.eval_table("oneshot")
    if not (mdm_path.is_file() and shots_path.is_file()):
        return []
    mdm, shots = by_method(read_csv(mdm_path)), by_method(read_csv(shots_path))
    lines = ["## One-shot learning with the mapper as initialiser (Tables 3-5)", ""]
    for method in method_order(mdm):
        if method == "bc":
            continue
        rows = shots.get(ONESHOT_PREFIX + method, {})
        if not rows:
            lines += [f"### {method_label(method)}: no failed seed to refit", ""]
            continue
        wins = sum(r["success"] for r in rows.values())
        lines += [f"### {method_label(method)}: {wins}/{len(rows)} failed seeds solved by one-shot", ""]
        cells = []
        for seed in sorted(rows):
            b, m, o = mdm["bc"][seed], mdm[method][seed], rows[seed]
            cells.append(
                (
                    seed,
                    f"{b['reward']:.1f}",
                    b["steps"],
                    f"{m['reward']:.1f}",
                    m["steps"],
                    f"{o['reward']:.1f}",
                    o["steps"],
                    "yes" if o["success"] else "no",
                )
            )
        lines += markdown_table(
            (
                "seed",
                "BC reward",
                "BC steps",
                "mapped reward",
                "mapped steps",
                "one-shot reward",
                "one-shot steps",
                "success",
            ),
            cells,
        ) + [""]
    return lines
