"""What every report section shares: rows grouped by method, percentages and success cells with
Wilson intervals, Markdown tables, figures that cannot cost the text."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from metadagger.imitation.metrics import summarize
from metadagger.utils.plotting import draw_figure


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
    """A Markdown table as lines (cells as given, converted with ``str``).

    Raises:
        ValueError: a row with another number of cells than the header (its cells would sit under
            the wrong columns).
    """
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        if len(row) != len(header):
            raise ValueError(f"a table row has {len(row)} cells under {len(header)} columns: {list(row)[:3]}")
        lines.append("| " + " | ".join(str(c) for c in row) + " |")
    return lines


def figure_lines(figures: Path, name: str, alt: str, draw: Callable[[Path], object]) -> list[str]:
    """Draw figure ``name`` into the report's ``figures`` folder with ``draw(path)``; its Markdown
    image line, or, if drawing failed (a warning on stderr), one line saying why in its place."""
    reason = draw_figure(figures / name, draw)
    if reason is None:
        return [f"![{alt}]({figures.name}/{name})"]
    return [f"Figure `{name}` could not be drawn ({reason})."]
