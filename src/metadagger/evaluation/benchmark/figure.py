"""The benchmark's figure: success against mean expert queries per seed, one panel per demonstration share.

Each method is drawn as its frontier: its points sorted by queries, keeping only those that raise
the success of every cheaper point (:func:`frontier`), joined by a post-step line with their 95%
Wilson intervals as error bars. Every method keeps one colour and one marker of its own across the
panels (:func:`method_styles`). Methods that ask the expert nothing (the MDM controls) are dashed
horizontal lines at their success; ``dagger-oracle``, which labels exactly where the learner is
wrong, is a reference (the learner's-mistakes rule, not a ceiling), drawn in black with dashes and
stars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.utils.plotting import interval_errors, plt, save_figure

#: The reference query rule: the learner is labelled exactly where it is wrong.
ORACLE = "dagger-oracle"
#: How the oracle is named when :func:`~metadagger.evaluation.benchmark.labels.method_label` does not know it.
ORACLE_FALLBACK = "oracle: labels exactly where the learner is wrong"
#: The oracle's own colour and marker, which no method gets.
ORACLE_COLOR, ORACLE_MARKER = "black", "*"
#: Method colours: tab10, then ten dark or saturated ones far from it (no black: the oracle's).
PALETTE = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
    "#000075",
    "#800000",
    "#008080",
    "#d100d1",
    "#4b5d16",
    "#c79200",
    "#4b0082",
    "#76c500",
    "#fa8072",
    "#a0522d",
)
#: Method markers, the most distinct first (no star: the oracle's).
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "p", "h", "d", "8", "H")
#: Sideways spread between points at one query count, as a share of the x axis's decades.
DODGE = 0.012
#: Most ticks placed at the points' own query counts; more become a 1-2-5 sequence.
MAX_TICKS = 8


@dataclass(frozen=True)
class Style:
    """How one method is drawn: its colour, its marker and whether the marker is filled."""

    color: str
    marker: str
    filled: bool = True


ORACLE_STYLE = Style(ORACLE_COLOR, ORACLE_MARKER)


def frontier(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the ``(queries, success)`` points on their frontier, cheapest first.

    Points are ordered by queries (at equal queries the higher success first); a point is kept when
    its success is strictly higher than that of every point before it, the first always.
    """
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1], i))
    kept: list[int] = []
    for i in order:
        if not kept or points[i][1] > points[kept[-1]][1]:
            kept.append(i)
    return kept


def method_styles(methods: Sequence[str]) -> dict[str, Style]:
    """Each method's style by its position among ``methods`` (the oracle apart, in black stars).

    Colours and markers both advance with the position, so no two methods share a colour while the
    palette lasts nor a marker while the markers last; past the markers they come back hollow.
    """
    styles: dict[str, Style] = {}
    for method in dict.fromkeys(methods):
        if method == ORACLE:
            styles[method] = ORACLE_STYLE
            continue
        i = len([m for m in styles if m != ORACLE])
        styles[method] = Style(PALETTE[i % len(PALETTE)], MARKERS[i % len(MARKERS)], i < len(MARKERS))
    return styles


def series_label(method: str) -> str:
    """The legend's name of a method: its table label, the oracle's fallback, or the name itself."""
    try:
        label = method_label(method)
    except Exception:  # a plug-in method the label registry does not know
        label = ORACLE_FALLBACK if method == ORACLE else method
    if method == ORACLE and not label.endswith("(reference)"):
        return f"{label} (reference)"
    return label


def control_label(method: str) -> str:
    """The legend's name of a method that asks no query, drawn as a horizontal reference line."""
    label = series_label(method)
    if label.endswith("(control)"):
        return label.removesuffix(")") + ", 0 queries)"
    return f"{label} (control, 0 queries)"


def panel_title(fraction: float) -> str:
    """A panel's title: the whole demonstration, or the share of it that the methods started from."""
    if fraction >= 1.0:
        return "whole demonstration"
    return f"first {100 * fraction:.3g}% of the demonstration"


def query_ticks(values: Sequence[float]) -> list[float]:
    """Ticks of the query axis: the points' own counts when there are at most :data:`MAX_TICKS`,
    each at least a ninth of their span (in decades, and 4%) above the last one kept, so that no
    two labels print over each other; else the 1-2-5 sequence across their range."""
    counts = sorted(set(values))
    if not counts:
        return []
    gap = max(math.log10(1.04), math.log10(counts[-1] / counts[0]) / 9)
    ticks: list[float] = []
    for v in counts:
        if not ticks or math.log10(v / ticks[-1]) >= gap * (1 - 1e-9):  # equal gaps count as wide enough
            ticks.append(v)
    if len(ticks) <= MAX_TICKS:
        return ticks
    low, high = math.floor(math.log10(ticks[0])), math.ceil(math.log10(ticks[-1]))
    steps = [m * 10.0**e for e in range(low, high + 1) for m in (1, 2, 5)]
    inside = [t for t in steps if ticks[0] <= t <= ticks[-1]]
    return inside if len(inside) >= 2 else [ticks[0], ticks[-1]]


def dodge(xs: Sequence[float], step: float) -> list[float]:
    """``xs`` spread sideways where several are equal: the k points at one value move to
    ``value * 10 ** (step * (j - (k - 1) / 2))``, j = 0..k-1 in the order given (log axes)."""
    groups: dict[float, list[int]] = {}
    for i, x in enumerate(xs):
        groups.setdefault(x, []).append(i)
    out = list(xs)
    for x, members in groups.items():
        for j, i in enumerate(members):
            out[i] = x * 10.0 ** (step * (j - (len(members) - 1) / 2))
    return out


def tick_label(value: float) -> str:
    """A query count as a tick label: whole above 100, else three significant digits."""
    return f"{value:.0f}" if value >= 100 else f"{value:.3g}"


def _panels(entries: Sequence[dict[str, Any]]) -> dict[float, dict[str, list[dict[str, Any]]]]:
    """Entries as ``{demo_fraction: {method: entries}}``, the whole demonstration first, then shorter shares."""
    fractions = sorted({float(e["demo_fraction"]) for e in entries}, key=lambda f: (f < 1.0, -f))
    panels: dict[float, dict[str, list[dict[str, Any]]]] = {f: {} for f in fractions}
    for e in entries:
        panels[float(e["demo_fraction"])].setdefault(e["method"], []).append(e)
    return panels


def _references(panels: dict[float, dict[str, list[dict[str, Any]]]]) -> dict[float, dict[str, list[dict[str, Any]]]]:
    """Each panel's zero-query entries by method: its own, else those of the first panel that has some
    (a method that asks no query reads no demonstration, so its line holds for every share)."""
    own = {
        fraction: {m: zero for m, group in methods.items() if (zero := [e for e in group if e["mean_queries"] <= 0])}
        for fraction, methods in panels.items()
    }
    carried: dict[str, list[dict[str, Any]]] = {}
    for refs in own.values():
        for method, zero in refs.items():
            carried.setdefault(method, zero)
    return {fraction: {m: refs.get(m, zero) for m, zero in carried.items()} for fraction, refs in own.items()}


def draw_queries(summary: dict[str, Any]) -> Figure:
    """Success (95% intervals) against mean expert queries per seed, log x, one panel per demonstration share.

    Per panel each method draws its :func:`frontier` as a post-step line with error bars; points of
    several methods at one query count are spread sideways (:func:`dodge`). Zero-query methods are
    dashed horizontal lines on every panel (they never read the demonstration), the oracle is the
    black reference, and one legend outside the axes names every series.
    """
    entries = list(summary["entries"])
    order = list(dict.fromkeys(e["method"] for e in entries))
    styles = method_styles(order)
    panels = _panels(entries) or {1.0: {}}
    refs = _references(panels)

    # Each panel's frontier points: (method, entry), methods in their stable order.
    shown_points: dict[float, list[tuple[str, dict[str, Any]]]] = {}
    for fraction, methods in panels.items():
        points: list[tuple[str, dict[str, Any]]] = []
        for method in order:
            paid = [e for e in methods.get(method, []) if float(e["mean_queries"]) > 0]
            keep = frontier([(float(e["mean_queries"]), float(e["success_rate"])) for e in paid])
            points.extend((method, paid[i]) for i in keep)
        shown_points[fraction] = points

    counts = [float(e["mean_queries"]) for points in shown_points.values() for _, e in points]
    span = math.log10(max(counts) / min(counts)) if counts else 0.0
    step = DODGE * max(span, 0.5)

    n = len(panels)
    fig, axes = plt.subplots(
        1, n, figsize=(5.2 * n + 3.6, 4.8), sharex=True, sharey=True, squeeze=False, layout="constrained"
    )
    handles: dict[str, tuple[Line2D, str]] = {}
    all_shown: list[float] = []
    for ax, (fraction, methods) in zip(axes[0], panels.items()):
        for method in order:
            style = styles[method]
            label = series_label(method) if method == ORACLE else control_label(method)
            for k, e in enumerate(refs[fraction].get(method, [])):
                line = ax.axhline(
                    float(e["success_rate"]),
                    color=style.color,
                    ls="--",
                    lw=1.4,
                    zorder=1,
                    label=label if k == 0 else "_nolegend_",
                )
                handles.setdefault(method + "\0ref", (line, label))
        points = shown_points[fraction]
        xs = dodge([float(e["mean_queries"]) for _, e in points], step)
        all_shown.extend(xs)
        for method in order:
            mine = [k for k, (m, _) in enumerate(points) if m == method]
            if not mine:
                continue
            chosen = [points[k][1] for k in mine]
            x = [xs[k] for k in mine]
            rates = [float(e["success_rate"]) for e in chosen]
            err = interval_errors(
                rates, [float(e["success_ci_low"]) for e in chosen], [float(e["success_ci_high"]) for e in chosen]
            )
            style = styles[method]
            oracle = method == ORACLE
            ax.errorbar(x, rates, yerr=err, fmt="none", ecolor=style.color, elinewidth=1.0, capsize=2.5, zorder=3)
            (line,) = ax.plot(
                x,
                rates,
                color=style.color,
                marker=style.marker,
                markersize=11 if oracle else 6,
                markerfacecolor=style.color if style.filled else "white",
                markeredgecolor=style.color,
                ls="--" if oracle else "-",
                lw=1.8 if oracle else 1.3,
                drawstyle="steps-post",
                zorder=5 if oracle else 4,
                label=series_label(method),
            )
            handles.setdefault(method, (line, series_label(method)))
        ax.set_title(panel_title(fraction))
        ax.grid(True, axis="y", alpha=0.3)

    first = axes[0][0]
    first.set_xscale("log")
    if all_shown:
        pad = 10.0 ** max(0.06 * span, 0.08)
        first.set_xlim(min(all_shown) / pad, max(all_shown) * pad)
        ticks = query_ticks(counts)
        first.set_xticks(ticks, [tick_label(t) for t in ticks])
    else:
        first.set_xlim(1.0, 10.0)
    shared = any(len({float(e["mean_queries"]) for _, e in pts}) < len(pts) for pts in shown_points.values())
    for ax in axes[0]:
        ax.minorticks_off()
        ax.set_xlabel(
            "mean expert queries per seed (log)" + ("\npoints at one count are spread sideways" if shared else "")
        )
    first.set_ylabel("success rate (95% Wilson interval)")
    first.set_ylim(-0.03, 1.03)

    # The methods' series in their order, then the reference lines, then the oracle.
    ranked = sorted(
        handles.items(),
        key=lambda kv: (kv[0].split("\0")[0] == ORACLE, kv[0].endswith("\0ref"), order.index(kv[0].split("\0")[0])),
    )
    if ranked:
        fig.legend(
            [h for _, (h, _) in ranked],
            [label for _, (_, label) in ranked],
            loc="outside right upper",
            fontsize="small",
            frameon=False,
        )
    return fig


def plot_queries(summary: dict[str, Any], path: Path) -> Path:
    """Draw :func:`draw_queries` of ``summary`` and save it as PNG at ``path``; the path written."""
    return save_figure(draw_queries(summary), path)


__all__ = [
    "Style",
    "control_label",
    "dodge",
    "draw_queries",
    "frontier",
    "method_styles",
    "panel_title",
    "plot_queries",
    "query_ticks",
    "series_label",
    "tick_label",
]
