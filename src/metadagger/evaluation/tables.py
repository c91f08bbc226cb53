"""What every report section shares: method labels, rows grouped by method, percentages and
success cells with Wilson intervals, Markdown tables, figures that cannot cost the text."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from metadagger.evaluation.methods import (
    DISAGREE_PREFIX,
    GATED_PRIOR,
    MDI_LABELS,
    PRIOR_DAGGER_PREFIX,
    PRIOR_PREFIX,
    benchmark_methods,
)
from metadagger.imitation.metrics import summarize
from metadagger.mapping.priors import ZERO
from metadagger.mapping.registry import get_kind, kind_names
from metadagger.utils.plotting import draw_figure


def method_label(method: str) -> str:
    """How tables name a method: a benchmark method's declared label (gates' included), an MDI
    protocol row, MDM with a mapper kind's registry label, a one-shot refit (``oneshot-<kind>``),
    or DAgger-MDI initialised by a control."""
    declared = benchmark_methods()
    if method in declared:
        return declared[method].label
    if method in MDI_LABELS:
        return MDI_LABELS[method]
    if method.startswith("mdm-"):
        return f"MDM {get_kind(method.removeprefix('mdm-')).label}"
    if GATED_PRIOR in method:
        gated, mean = method.split(GATED_PRIOR, 1)
        return f"{method_label(gated)}, prior toward {_mean_label(mean)}"
    if method.startswith(PRIOR_DAGGER_PREFIX):
        return f"DAgger, prior toward {_mean_label(method.removeprefix(PRIOR_DAGGER_PREFIX))}"
    if method.startswith(PRIOR_PREFIX):
        return f"BC, prior toward {_mean_label(method.removeprefix(PRIOR_PREFIX))}"
    if method.startswith(DISAGREE_PREFIX):
        return f"DAgger, gate: disagreement with {get_kind(method.removeprefix(DISAGREE_PREFIX)).label}"
    if method.startswith("oneshot-"):
        return f"one-shot {get_kind(method.removeprefix('oneshot-')).label}"
    if method.startswith("dagger-mdi-"):
        return f"control: DAgger-MDI initialised by {method.removeprefix('dagger-mdi-')}"
    return get_kind(method).label


def _mean_label(mean: str) -> str:
    return "zero" if mean == ZERO else get_kind(mean).label


def method_order(methods: Iterable[str]) -> list[str]:
    """``methods`` with BC first, then the mapper kinds in registry order, then the rest as given."""
    methods = list(dict.fromkeys(methods))
    known = ["bc", *kind_names()]
    return [m for m in known if m in methods] + [m for m in methods if m not in known]


def by_method(rows: Iterable[dict[str, Any]]) -> dict[str, dict[int, dict[str, Any]]]:
    """Rows as ``{method: {seed: row}}``, methods in the order they first appear."""
    table: dict[str, dict[int, dict[str, Any]]] = defaultdict(dict)
    for r in rows:
        table[r["method"]][r["seed"]] = r
    return dict(table)


def pct(x: float) -> str:
    """A share as a percentage with one decimal."""
    return f"{100 * x:.1f}%"


def rate(rows: Iterable[dict[str, Any]], key: str = "success") -> str:
    """``share (successes/n; low-high)`` of a boolean column, with its 95% Wilson interval."""
    s = summarize({"success": r[key], "reward": 0.0, "steps": 0} for r in rows)
    return (
        f"{pct(s['success_rate'])} ({s['successes']}/{s['episodes']}; "
        f"{pct(s['success_ci_low'])}-{pct(s['success_ci_high'])})"
    )


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A Markdown table as lines (cells as given, converted with ``str``)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def figure_lines(figures: Path, name: str, alt: str, draw: Callable[[Path], object]) -> list[str]:
    """Draw figure ``name`` into the report's ``figures`` folder with ``draw(path)``; its Markdown
    image line, or, if drawing failed (a warning on stderr), one line saying why in its place."""
    reason = draw_figure(figures / name, draw)
    if reason is None:
        return [f"![{alt}]({figures.name}/{name})"]
    return [f"Figure `{name}` could not be drawn ({reason})."]
