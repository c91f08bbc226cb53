"""The report sections on what a run built before evaluating: pi*, the pairs, and the mappers
(learning curves, paper Fig. 8, and each mapper's weight-space validation error beside the
controls'). Built only from the run's JSON and CSV files."""

from __future__ import annotations


from metadagger.evaluation.curves import plot_curves
from metadagger.evaluation.rows import CURVE_COLUMNS, read_csv
from metadagger.evaluation.tables import markdown_table, method_label, pct
from metadagger.mapping.registry import get_kind, kind_names
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json


def groundtruth_section(layout: RunLayout) -> list[str]:
    """pi*'s success on its own and on unseen seeds, and the expert queries it cost."""
    if not layout.groundtruth_metrics.is_file():
        return []
    m = read_json(layout.groundtruth_metrics, "pi*'s metrics")
    cells = []
    for key, name in (("own_seeds", "its own (training) seeds"), ("unseen_seeds", "unseen seeds")):
        s = m[key]
        cells.append((name, f"{s['successes']}/{s['episodes']}", pct(s["success_rate"]),
                      f"{pct(s['success_ci_low'])}-{pct(s['success_ci_high'])}", f"{s['mean_reward']:.1f}", f"{s['mean_steps']:.0f}"))
    return (["## Ground-truth policy pi*", ""]
            + markdown_table(("seeds", "successes", "success", "95% CI", "mean reward", "mean steps"), cells)
            + ["", f"Expert queries spent on pi*: {m.get('expert_queries', 0)}.", ""] + _selection_lines(m))


def _selection_lines(metrics: dict) -> list[str]:
    """Which epoch of the BC fit became pi* when it was chosen on held-out seeds."""
    choice = metrics.get("bc_selection")
    if not choice:
        return []
    checks = ", ".join(f"epoch {c['epoch']}: {c['successes']}" for c in choice["history"])
    return [f"pi* is epoch {choice['epoch']} of its BC fit, chosen on {choice['episodes']} held-out seeds of its own "
            f"(groundtruth.select_seeds), where it succeeded {choice['successes']} times; every check: {checks}.", ""]


def pairs_section(layout: RunLayout) -> list[str]:
    """The four outcomes of the per-seed pairs and how many were kept."""
    if not layout.pairs_summary.is_file():
        return []
    s = read_json(layout.pairs_summary, "the pairs summary")
    cells = [(name.replace("_", " ").replace("/", ", "), count, pct(s["shares"][name])) for name, count in s["outcomes"].items()]
    return ["## Pairs (w_BC, w_DA)", "", f"{s['seeds']} seeds, {s['kept']} pairs kept.", ""] + markdown_table(("outcome", "seeds", "share"), cells) + [""]


def mappers_section(layout: RunLayout) -> list[str]:
    """Weight-space error of every trained mapper on the training and validation pairs, as a
    multiple of the mean-DA control's, and the learned kinds' learning curves (Fig. 8)."""
    finals = {}
    for kind in kind_names():
        if layout.mapper_curves(kind).is_file():
            rows = [r for r in read_csv(layout.mapper_curves(kind), columns=CURVE_COLUMNS) if r["val_mse_weights"] != ""]
            if rows:
                finals[kind] = rows[-1]
    if not finals:
        return []
    lines = ["## Mappers", "", "### Weight-space error after training (MSE of f(w_BC) against w_DA, original units)", ""]
    base = finals.get("mean-da")
    cells = []
    for kind, r in finals.items():
        ratio = f"{r['val_mse_weights'] / base['val_mse_weights']:.2f}" if base and base["val_mse_weights"] else "-"
        cells.append((method_label(kind), f"{r['train_mse_weights']:.4g}", f"{r['val_mse_weights']:.4g}", ratio))
    lines += markdown_table(("mapper", "train MSE", "validation MSE", "validation MSE / mean-DA's"), cells)
    lines += ["", "A ratio near or above 1 means the mapper predicts an unseen seed's w_DA no better than the "
              "training pairs' mean w_DA, whatever its training error.", ""]
    figures = []
    for kind in finals:
        if get_kind(kind).learned:
            plot_curves(layout.mapper_curves(kind), layout.figures / f"curves_{kind}.png")
            figures += [f"![{method_label(kind)} learning curves](figures/curves_{kind}.png)", ""]
    return lines + (["### Learning curves (Fig. 8)", "", *figures] if figures else [])
