"""The success-against-queries figure: frontiers, one style per method, controls as lines, a panel per share."""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import pytest
from matplotlib.colors import to_hex
from matplotlib.lines import Line2D

from metadagger.evaluation.benchmark import figure as benchmark_figure
from metadagger.evaluation.benchmark.figure import (
    MARKERS,
    ORACLE_FALLBACK,
    PALETTE,
    control_label,
    draw_queries,
    frontier,
    method_styles,
    plot_queries,
    series_label,
)
from metadagger.utils.plotting import plt

GATES = ("random", "ensemble", "safe", "novelty", "thrifty", "conformal")
DEMO = 40.0


def entry(method: str, setting: str, fraction: float, queries: float, rate: float, seeds: int = 10) -> dict[str, Any]:
    """One summary entry with a crude interval around ``rate`` (clamped to [0, 1])."""
    return {
        "method": method,
        "setting": setting,
        "demo_fraction": fraction,
        "seeds": seeds,
        "successes": round(rate * seeds),
        "success_rate": rate,
        "success_ci_low": max(0.0, rate - 0.15),
        "success_ci_high": min(1.0, rate + 0.15),
        "mean_reward": 10 * rate,
        "mean_queries": queries,
    }


def summary() -> dict[str, Any]:
    """A benchmark summary made by hand: 15 methods (BC, five MDM kinds of which two controls, DAgger
    rounds, the refit control, six gates of three settings, the oracle) on the whole demonstration and
    on its first quarter."""
    entries = []
    for fraction in (1.0, 0.25):
        demo = DEMO * fraction
        entries.append(entry("bc", "", fraction, demo, 0.3 * fraction + 0.1))
        for kind, rate in (("dm", 0.55), ("sam", 0.5), ("ridge", 0.45)):
            entries.append(entry(f"mdm-{kind}", "", fraction, demo, rate * (0.5 + fraction / 2)))
        if fraction == 1.0:
            entries.append(entry("mdm-pistar-head", "", fraction, 0.0, 0.2))
            entries.append(entry("mdm-mean-da", "", fraction, 0.0, 0.35))
            for r in range(1, 5):  # a dip in round 3: off the frontier
                entries.append(entry("dagger", str(r), fraction, demo + 100.0 * r, (0.5, 0.7, 0.6, 0.8)[r - 1]))
            entries.append(entry("bc-refit", "", fraction, demo, 0.4))
        for g, gate in enumerate(GATES):
            for s, share in enumerate((0.1, 0.3, 0.6)):
                rate = min(1.0, 0.35 + 0.08 * g + 0.1 * s) * (0.6 + 0.4 * fraction)
                entries.append(entry(f"dagger-{gate}", f"{share}", fraction, demo + 400.0 * share, rate))
        entries.append(entry("dagger-oracle", "", fraction, demo + 60.0, 0.95))
        entries.append(entry("dagger-oracle", "late", fraction, demo + 200.0, 1.0))
    return {"entries": entries}


def series(fig) -> list[Line2D]:
    """The labelled lines (one per series and panel) of every panel of ``fig``."""
    return [line for ax in fig.axes for line in ax.get_lines() if not line.get_label().startswith("_")]


def is_horizontal(line: Line2D) -> bool:
    ys = list(line.get_ydata())
    return len(set(ys)) == 1 and list(line.get_xdata()) == [0, 1]


@pytest.fixture(scope="module")
def figure():
    fig = draw_queries(summary())
    yield fig
    plt.close(fig)


@pytest.mark.parametrize(
    ("points", "expected"),
    [
        ([(5.0, 0.4)], [0]),
        ([(10.0, 0.5), (20.0, 0.5), (30.0, 0.6)], [0, 2]),  # a tie in success is not a gain
        ([(10.0, 0.9), (20.0, 0.7), (30.0, 0.5)], [0]),  # success only falls: the cheapest alone
        ([(30.0, 0.8), (10.0, 0.2), (20.0, 0.6)], [1, 2, 0]),  # given out of query order
        ([(10.0, 0.3), (10.0, 0.7), (20.0, 0.6), (40.0, 0.9)], [1, 3]),  # at equal queries the better one
        ([(10.0, 0.0), (20.0, 0.0)], [0]),  # zero success everywhere
        ([], []),
    ],
)
def test_frontier(points, expected):
    assert frontier(points) == expected


def test_styles_are_stable_and_distinct():
    methods = ["bc", *(f"dagger-x{i}" for i in range(len(PALETTE) - 1)), "dagger-oracle"]
    assert len(PALETTE) >= 16
    styles = method_styles(methods)
    assert styles == method_styles([*methods, "bc"])  # first appearance decides
    drawn = [styles[m] for m in methods if m != "dagger-oracle"]
    assert len({s.color for s in drawn}) == len(drawn) == len(PALETTE)
    assert len({s.marker for s in drawn[: len(MARKERS)]}) == len(MARKERS)
    assert len({(s.marker, s.filled) for s in drawn}) == len(drawn)  # past the markers they come back hollow
    assert styles["dagger-oracle"].color == "black" and styles["dagger-oracle"].marker == "*"
    assert all(s.color != "black" and s.marker != "*" for s in drawn)


def test_labels(monkeypatch):
    oracle = series_label("dagger-oracle")
    assert oracle.endswith(" (reference)") and oracle.count("reference") == 1
    assert series_label("bc") == "BC"
    assert series_label("dagger-plugin") == "dagger-plugin"  # a plug-in gate the labels do not know
    assert control_label("mdm-mean-da") == "MDM mean-DA (control, 0 queries)"

    def unknown(method: str) -> str:
        raise ValueError(method)

    monkeypatch.setattr(benchmark_figure, "method_label", unknown)
    assert series_label("dagger-oracle") == f"{ORACLE_FALLBACK} (reference)"


def test_one_panel_per_demo_fraction(figure):
    titles = [ax.get_title() for ax in figure.axes]
    assert titles == ["whole demonstration", "first 25% of the demonstration"]
    assert all(ax.get_xscale() == "log" for ax in figure.axes)
    assert figure.axes[0].get_ylim() == pytest.approx((-0.03, 1.03))
    (legend,) = figure.legends
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels[0] == "BC" and labels[-1].endswith("(reference)") and len(labels) == len(set(labels)) == 15


def test_every_series_has_its_own_colour_and_marker(figure):
    style: dict[str, tuple[str, str]] = {}
    for line in series(figure):
        drawn = (to_hex(line.get_color()), line.get_marker())
        assert style.setdefault(line.get_label(), drawn) == drawn  # same style in every panel
    markers = {label: s for label, s in style.items() if s[1] not in ("None", None, "")}
    assert len(style) == 15
    assert len({c for c, _ in style.values()}) == len(style)
    assert len({m for _, m in markers.values()}) == len(markers) == 13
    oracle = [label for label in style if label.endswith("(reference)")]
    assert len(oracle) == 1 and style[oracle[0]] == ("#000000", "*")


def test_controls_are_horizontal_lines_on_every_panel(figure):
    for ax in figure.axes:
        controls = [line for line in ax.get_lines() if "0 queries" in line.get_label()]
        assert len(controls) == 2
        assert all(is_horizontal(line) for line in controls)
        assert sorted(line.get_ydata()[0] for line in controls) == pytest.approx([0.2, 0.35])


def test_lines_follow_the_frontier_as_steps(figure):
    whole = figure.axes[0]
    (dagger,) = [line for line in whole.get_lines() if line.get_label() == "DAgger"]
    assert list(dagger.get_ydata()) == pytest.approx([0.5, 0.7, 0.8])  # round 3's dip is left out
    assert dagger.get_drawstyle() == "steps-post"
    xs = list(dagger.get_xdata())
    assert xs == sorted(xs)


def test_points_at_one_count_are_spread(figure):
    whole = figure.axes[0]
    at_demo = [
        line.get_xdata()[0]
        for line in whole.get_lines()
        if line.get_label() in ("BC", "MDM DM", "MDM SAM", "MDM Ridge")
    ]
    assert len(at_demo) == 4 and len(set(at_demo)) == 4
    assert all(math.isclose(x, DEMO, rel_tol=0.2) for x in at_demo)


@pytest.mark.parametrize(
    "entries",
    [
        [entry("bc", "", 1.0, 40.0, 0.5)],
        [entry("bc", "", 1.0, 40.0, 0.0), entry("dagger-safe", "a", 1.0, 90.0, 0.0)],
        [entry("dagger-plugin", s, 1.0, 70.0, r) for s, r in (("a", 0.2), ("b", 0.4), ("c", 0.1))],
        [entry("mdm-pistar-head", "", 1.0, 0.0, 0.2)],
        [],
    ],
    ids=["only-bc", "zero-success", "equal-queries", "only-a-control", "empty"],
)
def test_odd_summaries_still_draw(entries):
    fig = draw_queries({"entries": entries})
    try:
        assert len(fig.axes) == 1
        fig.savefig(io.BytesIO(), format="png", dpi=20, bbox_inches="tight")  # lays out and renders
    finally:
        plt.close(fig)


def test_png_is_written(tmp_path: Path):
    path = plot_queries(summary(), tmp_path / "queries.png")
    assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
