"""Matplotlib set up for files only (Agg backend), and an atomic figure save."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from metadagger.utils.io import atomic_write  # noqa: E402


def save_figure(fig: "plt.Figure", path: str | Path) -> Path:
    """Save ``fig`` as PNG atomically and close it."""
    try:
        return atomic_write(path, lambda p: fig.savefig(p, format="png", dpi=120, bbox_inches="tight"))
    finally:
        plt.close(fig)


__all__ = ["plt", "save_figure"]
