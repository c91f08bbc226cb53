"""Mapper learning curves (paper Fig. 8), drawn from a mapper's ``curves.csv`` alone."""

from __future__ import annotations

import csv
from pathlib import Path

from matplotlib.ticker import MaxNLocator

from metadagger.utils.plotting import plt, save_figure


def _value(row: dict[str, str], key: str) -> float | None:
    return float(row[key]) if row[key] else None


def plot_curves(csv_path: str | Path, png_path: str | Path) -> Path:
    """Draw ``curves.csv`` as paper Fig. 8: train/val loss per epoch, one panel per model.

    A last panel shows the whole mapping's MSE in weight units (the only panel of a control). A
    panel with one point (a closed-form fit, a control) is no curve: it says so in one line and
    gives the two numbers instead of a dot on an epoch axis.
    """
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    models = list(dict.fromkeys(r["model"] for r in rows if r["train_loss"]))
    mapped = [r for r in rows if r["val_mse_weights"] or r["train_mse_weights"]]
    panels = [
        (
            m,
            [r for r in rows if r["model"] == m],
            "train_loss",
            "val_loss",
            "MSE (latent codes)" if m == "h" else "MSE (standardised)",
        )
        for m in models
    ]
    if mapped:
        panels.append(("whole mapping f", mapped, "train_mse_weights", "val_mse_weights", "MSE (weight units)"))
    height = 3.4 if any(len(data) > 1 for _, data, *_ in panels) else 1.0
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), height), squeeze=False, layout="constrained")
    for ax, (title, data, train_key, val_key, ylabel) in zip(axes[0], panels):
        if len(data) == 1:
            ax.axis("off")
            ax.set_title(f"{title}: one point, no curve")
            values = ", ".join(
                f"{label} {v:.3g}"
                for key, label in ((train_key, "train"), (val_key, "validation"))
                if (v := _value(data[0], key)) is not None
            )
            ax.text(0.5, 0.5, f"{ylabel}: {values}", ha="center", va="center", transform=ax.transAxes)
            continue
        ax.set_title(title)
        epochs = [int(r["epoch"]) for r in data]
        for key, label in ((train_key, "train"), (val_key, "validation")):
            values = [_value(r, key) for r in data]
            ax.plot(epochs, [float("nan") if v is None else v for v in values], label=label)
        ax.set_yscale("log")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("epoch")
        ax.set_ylabel(ylabel)
        ax.legend()
    return save_figure(fig, png_path)
