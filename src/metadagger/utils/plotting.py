"""Matplotlib set up for files only (Agg backend), an atomic figure save, error bars from
intervals, and a figure drawn without risking what was computed before it."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from metadagger.utils.io import atomic_write  # noqa: E402

#: How far (in the interval's units) a bound may lie beyond its centre and still count as rounding.
ROUNDING = 1e-9


def save_figure(fig: "plt.Figure", path: str | Path) -> Path:
    """Save ``fig`` as PNG atomically and close it."""
    try:
        return atomic_write(path, lambda p: fig.savefig(p, format="png", dpi=120, bbox_inches="tight"))
    finally:
        plt.close(fig)


def interval_errors(centres: Sequence[float], lows: Sequence[float], highs: Sequence[float]) -> list[list[float]]:
    """``yerr`` for :meth:`~matplotlib.axes.Axes.errorbar`: ``[below, above]`` each centre.

    A bound beyond its centre by a rounding error (a Wilson bound of 0/n or n/n written before
    :func:`~metadagger.imitation.metrics.wilson_interval` clamped) counts as on it.

    Raises:
        ValueError: the lengths differ, or an interval excludes its centre by more than rounding.
    """
    if not len(centres) == len(lows) == len(highs):
        raise ValueError(
            f"interval_errors needs as many lows and highs as centres, got {len(centres)}, {len(lows)}, {len(highs)}"
        )
    below, above = [], []
    for centre, low, high in zip(centres, lows, highs):
        if low - centre > ROUNDING or centre - high > ROUNDING:
            raise ValueError(f"interval [{low}, {high}] does not hold its centre {centre}")
        below.append(max(0.0, centre - low))
        above.append(max(0.0, high - centre))
    return [below, above]


def draw_figure(path: Path, draw: Callable[[Path], object]) -> str | None:
    """Call ``draw(path)``, which draws and saves one figure; None when it did.

    A figure is a view of rows and summaries already written, so a failure costs only the figure:
    its exception becomes one warning line on stderr naming ``path``, any figure it left open is
    closed, and the reason (one line) is returned for the caller to note in place of the figure.
    """
    opened = set(plt.get_fignums())
    try:
        draw(path)
    except Exception as exc:  # any failure of matplotlib or of the drawing code: only the figure is lost
        for number in set(plt.get_fignums()) - opened:
            plt.close(number)
        reason = " ".join(f"{type(exc).__name__}: {exc}".split())
        print(f"warning: figure {path} was not drawn ({reason})", file=sys.stderr)
        return reason
    return None


__all__ = ["draw_figure", "interval_errors", "plt", "save_figure"]
