"""Mapper learning curves (paper Fig. 8), drawn from a mapper's ``curves.csv`` alone."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from metadagger.utils.plotting import plt, save_figure


def plot_curves(csv_path: str | Path, png_path: str | Path) -> Path:
    """Draw ``curves.csv`` as paper Fig. 8: train/val loss per epoch, one panel per model.

    A last panel shows the whole mapping's MSE in weight units (the only panel of a control).
    """
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    models = list(dict.fromkeys(r["model"] for r in rows if r["train_loss"]))
    mapped = [r for r in rows if r["val_mse_weights"] or r["train_mse_weights"]]
    panels = [
        (m, [r for r in rows if r["model"] == m], "train_loss", "val_loss", "MSE (latent codes)" if m == "h" else "MSE (standardised)")
        for m in models
    ]
    if mapped:
        panels.append(("whole mapping f", mapped, "train_mse_weights", "val_mse_weights", "MSE (weight units)"))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.4), squeeze=False, layout="constrained")
    for ax, (title, data, train_key, val_key, ylabel) in zip(axes[0], panels):
        epochs = [int(r["epoch"]) for r in data]
        for key, label in ((train_key, "train"), (val_key, "validation")):
            values = [float(r[key]) if r[key] else math.nan for r in data]
            ax.plot(epochs, values, marker="o" if len(data) == 1 else None, label=label)
        ax.set_yscale("log")
        ax.set_title(title)
        ax.set_xlabel("epoch")
        ax.set_ylabel(ylabel)
        ax.legend()
    return save_figure(fig, png_path)
