"""The report sections on the run itself and what it built before evaluating: each stage's wall
time, pi*, the pairs and their train/validation split, and the mappers (learning curves, paper
Fig. 8, and each mapper's weight-space validation error beside the controls'). Built only from
the run's config and its JSON and CSV files."""

from __future__ import annotations

import json
import math
from typing import Any

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.curves import plot_curves
from metadagger.evaluation.report.tables import figure_lines, markdown_table, pct
from metadagger.evaluation.rows import CURVE_COLUMNS, read_csv
from metadagger.mapping.registry import get_kind, kind_names
from metadagger.metal_dagger.store import validation_size
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json
from metadagger.utils.yaml_config import read_run_data

#: The pipeline's stages in run order; the stage times of any other stage follow them as written.
STAGE_ORDER = ("pistar", "pairs", "mappers", "evaluate", "mdi", "benchmark")


def run_section(layout: RunLayout) -> list[str]:
    """Each finished stage's wall time and when it finished, from ``stage_times.json``; [] when
    the run has none, one line when the file cannot be read."""
    path = layout.stage_times
    if not path.is_file():
        return []
    lines = ["## Run", ""]
    try:
        times = _stage_times(json.loads(path.read_text()))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return lines + [f"Stage wall times: `{path.name}` could not be read ({' '.join(str(exc).split())}).", ""]
    if not times:
        return lines + [f"Stage wall times: `{path.name}` names no stage.", ""]
    stages = [s for s in STAGE_ORDER if s in times] + [s for s in times if s not in STAGE_ORDER]
    totals = {s: times[s].get("total_seconds", times[s]["seconds"]) for s in stages}
    reruns = any(totals[s] != times[s]["seconds"] for s in stages)  # a stage resumed or rebuilt: show its sum too
    cells = [
        (s, duration(times[s]["seconds"]), *([duration(totals[s])] if reruns else []), times[s]["finished"])
        for s in stages
    ]
    cells.append(("all stages", duration(sum(times[s]["seconds"] for s in stages)), *([""] if reruns else []), ""))
    header = ("stage", "wall time", *(["all calls"] if reruns else []), "finished")
    note = (
        "Wall time of each stage's last call"
        + ("; all calls: summed over every call of the stage" if reruns else "")
        + "."
    )
    return lines + [note, ""] + markdown_table(header, cells) + [""]


def _stage_times(data: Any) -> dict[str, dict[str, Any]]:
    """``stage_times.json`` checked: a stage name to its ``seconds`` (and ``total_seconds``: finite,
    not negative) and ``finished`` (text)."""
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object of stages, got {type(data).__name__}")
    for stage, entry in data.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("finished"), str):
            raise ValueError(f'stage {stage!r}: expected {{"seconds": ..., "finished": "..."}}, got {str(entry)[:80]}')
        for key in ("seconds", *(("total_seconds",) if "total_seconds" in entry else ())):
            value = entry.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ValueError(f"stage {stage!r}: {key} must be a number of seconds, got {value!r}")
    return data


def duration(seconds: float) -> str:
    """``12.3 s``, ``4 min 05 s`` or ``2 h 03 min``."""
    if round(seconds, 1) < 60:
        return f"{seconds:.1f} s"
    if round(seconds) < 3600:
        minutes, secs = divmod(round(seconds), 60)
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(round(seconds / 60), 60)
    return f"{hours} h {minutes:02d} min"


def pistar_section(layout: RunLayout) -> list[str]:
    """pi*'s success on its own and on unseen seeds, and the expert queries it cost."""
    if not layout.pistar_metrics.is_file():
        return []
    m = read_json(layout.pistar_metrics, "pi*'s metrics")
    cells = []
    for key, name in (("own_seeds", "its own (training) seeds"), ("unseen_seeds", "unseen seeds")):
        s = m[key]
        cells.append(
            (
                name,
                f"{s['successes']}/{s['episodes']}",
                pct(s["success_rate"]),
                f"{pct(s['success_ci_low'])}-{pct(s['success_ci_high'])}",
                f"{s['mean_reward']:.1f}",
                f"{s['mean_steps']:.0f}",
            )
        )
    return (
        ['## pi*, the "ground truth" policy', ""]
        + markdown_table(("seeds", "successes", "success", "95% CI", "mean reward", "mean steps"), cells)
        + ["", f"Expert queries spent on pi*: {m.get('expert_queries', 0)}.", ""]
        + _selection_lines(m)
        + _origin_lines(layout)
    )


def _origin_lines(layout: RunLayout) -> list[str]:
    """Where pi* was made, when the run took it from the machine's cache."""
    if not layout.pistar_origin.is_file():
        return []
    origin = read_json(layout.pistar_origin, "pi*'s origin")
    took = origin_took(origin)
    commits = ", ".join(c[:7] for c in origin.get("commits") or []) or "unknown"
    return [
        f"pi* was taken from the machine's cache: run `{origin['run']}` made it{took} (commit {commits}); "
        "its stage time here is the copy's, and the files are what training it here would write.",
        "",
    ]


def origin_took(origin: dict) -> str:
    """`` in 3 min 46 s``: the wall time that made a pi* taken from the cache (``pistar/origin.json``),
    or "" where none was recorded."""
    return f" in {duration(origin['seconds'])}" if origin.get("seconds") is not None else ""


def _selection_lines(metrics: dict) -> list[str]:
    """Which epoch of the BC fit became pi* when it was chosen on held-out seeds."""
    choice = metrics.get("bc_selection")
    if not choice:
        return []
    checks = ", ".join(f"epoch {c['epoch']}: {c['successes']}" for c in choice["history"])
    return [
        f"pi* is epoch {choice['epoch']} of its BC fit, chosen on {choice['episodes']} held-out seeds of its own "
        f"(pistar.select_seeds), where it succeeded {choice['successes']} times; every check: {checks}.",
        "",
    ]


def pairs_section(layout: RunLayout) -> list[str]:
    """The four outcomes of the per-seed pairs, how many were kept, and how the kept pairs split
    into the mappers' training and validation pairs."""
    if not layout.pairs_summary.is_file():
        return []
    s = read_json(layout.pairs_summary, "the pairs summary")
    cells = [
        (name.replace("_", " ").replace("/", ", "), count, pct(s["shares"][name]))
        for name, count in s["outcomes"].items()
    ]
    return (
        ["## Pairs (w_BC, w_DA)", "", f"{s['seeds']} seeds, {s['kept']} pairs kept.", ""]
        + markdown_table(("outcome", "seeds", "share"), cells)
        + [""]
        + _split_lines(layout, s["kept"])
    )


def _split_lines(layout: RunLayout, kept: int) -> list[str]:
    """How many kept pairs train the mappers and how many validate them (the config's
    ``pairs.val_fraction`` and ``split_seed``); [] for a config without them."""
    config = read_run_data(layout.config)
    fraction, seed = config.get("pairs", {}).get("val_fraction"), config.get("split_seed")
    if fraction is None or seed is None:
        return []
    val = validation_size(kept, fraction)
    settings = f"pairs.val_fraction {fraction:g}, split_seed {seed}"
    if kept - val < 1:
        return [f"Train/validation split: {kept} kept pairs are too few for a training set ({settings}).", ""]
    return [
        f"Train/validation split: the mappers train on {kept - val} of the {kept} kept pairs and validate on {val} "
        f"({settings}: a seeded permutation of the kept seeds).",
        "",
    ]


def mappers_section(layout: RunLayout) -> list[str]:
    """Weight-space error of every trained mapper on the training and validation pairs, as a
    multiple of the mean-DA control's, and the learning curves (Fig. 8) of the kinds trained over
    epochs (a closed-form fit or a control has one point: no curve)."""
    finals, epochs = {}, {}
    for kind in kind_names():
        if layout.mapper_curves(kind).is_file():
            rows = read_csv(layout.mapper_curves(kind), columns=CURVE_COLUMNS)
            mapped = [r for r in rows if r["val_mse_weights"] != ""]
            if mapped:
                finals[kind], epochs[kind] = mapped[-1], len({r["epoch"] for r in rows})
    if not finals:
        return []
    lines = [
        "## Mappers",
        "",
        "### Weight-space error after training (MSE of f(w_BC) against w_DA, original units)",
        "",
    ]
    base = finals.get("mean-da")
    cells = []
    for kind, r in finals.items():
        ratio = f"{r['val_mse_weights'] / base['val_mse_weights']:.2f}" if base and base["val_mse_weights"] else "-"
        cells.append((method_label(kind), f"{r['train_mse_weights']:.4g}", f"{r['val_mse_weights']:.4g}", ratio))
    lines += markdown_table(("mapper", "train MSE", "validation MSE", "validation MSE / mean-DA's"), cells)
    lines += [
        "",
        "A ratio near or above 1 means the mapper predicts an unseen seed's w_DA no better than the "
        "training pairs' mean w_DA, whatever its training error.",
        "",
    ]
    figures = []
    for kind in (k for k in finals if epochs[k] > 1):
        figures += figure_lines(
            layout.figures,
            f"curves_{kind}.png",
            f"{method_label(kind)} learning curves",
            lambda path, kind=kind: plot_curves(layout.mapper_curves(kind), path),
        ) + [""]
    single = [k for k in finals if epochs[k] == 1]
    return (
        lines
        + ["### Learning curves (Fig. 8)", "", *figures]
        + _no_curve_lines(
            [method_label(k) for k in single if get_kind(k).learned],
            [method_label(k) for k in single if not get_kind(k).learned],
        )
    )


def _no_curve_lines(closed: list[str], constant: list[str]) -> list[str]:
    """Why the kinds with one point (closed-form fits, constant controls) have no curve."""
    parts = []
    if closed:
        parts.append(f"{', '.join(closed)} {'is' if len(closed) == 1 else 'are'} fitted in closed form")
    if constant:
        parts.append(f"{', '.join(constant)} {'is a constant' if len(constant) == 1 else 'are constants'}")
    return (
        [f"{'; '.join(parts)}: one point each, so no learning curve (their errors are in the table above).", ""]
        if parts
        else []
    )
