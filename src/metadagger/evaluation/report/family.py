"""The task-family section of a report: did a method learn the seed's variation?

Per unseen seed, the variation it drew beside every method's outcome (MDM methods and controls,
the MDI protocol's one-shot outcomes, DAgger after its last benchmark round); each method's
success on the seeds with the smaller and the larger half of the variations; and a figure of
success against the variation's size. Built from the run's CSV files and its config (a seed's
variation is a pure function of the seed: ``Task.variation_of``).
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.labels import method_label, method_order
from metadagger.evaluation.report.tables import by_method, figure_lines, markdown_table, rate
from metadagger.evaluation.rows import read_csv
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks import make_task
from metadagger.tasks.base import Task
from metadagger.utils.plotting import plt, save_figure
from metadagger.utils.yaml_config import read_run_data

FIGURE = "family_variation.png"


def family_section(layout: RunLayout) -> list[str]:
    """Variation beside outcome per seed, success by variation size, and the figure; [] for a plain
    task or a run without per-seed evaluations."""
    task = _run_task(layout)
    if task is None or task.variation_of(0) is None:  # a plain task: no variations to show
        return []
    outcomes = _outcomes(layout)
    if not outcomes:
        return []
    seeds = sorted({s for per_seed in outcomes.values() for s in per_seed})
    variations = {s: task.variation_of(s) for s in seeds}
    sizes = {s: task.variation_size(variations[s]) for s in seeds}
    methods = list(outcomes)
    lines = [
        "## Task family: the seed's variation beside each method's outcome",
        "",
        f"Each unseen seed draws a variation the learner never observes (`{task.name}`, docs/families.md); "
        "its size is how far the seed's system is from the nominal one pi* was trained on. "
        "A method that learned the variation from the demonstration succeeds on large variations too; "
        "pi*'s head (the nominal member's policy) should not.",
        "",
    ]
    median = statistics.median(sizes.values())
    small = {s for s in seeds if sizes[s] <= median}
    lines += [f"### Success on the smaller and the larger half of the variations (size <= {median:.3f} and above)", ""]
    lines += markdown_table(
        ("method", f"small ({_seeds(len(small))})", f"large ({_seeds(len(seeds) - len(small))})", "all"),
        [
            (
                label,
                rate(r for s, r in outcomes[label].items() if s in small),
                rate(r for s, r in outcomes[label].items() if s not in small),
                rate(outcomes[label].values()),
            )
            for label in methods
        ],
    )
    lines += ["", "### Per seed (✓ success, ✗ failure, - not run)", ""]
    keys = sorted(variations[seeds[0]])
    lines += markdown_table(
        ("seed", *keys, "size", *methods),
        [
            (
                s,
                *(f"{variations[s][k]:+.3f}" for k in keys),
                f"{sizes[s]:.3f}",
                *(_mark(outcomes[m].get(s)) for m in methods),
            )
            for s in seeds
        ],
    )
    return (
        lines
        + ["", "### Success against the variation's size (one marker per seed; filled: success)", ""]
        + figure_lines(layout.figures, FIGURE, "success against variation", lambda path: _figure(outcomes, sizes, path))
        + [""]
    )


def _run_task(layout: RunLayout) -> Task | None:
    if not layout.config.is_file():
        return None
    config = read_run_data(layout.config)
    if "task" not in config:
        return None
    steps = {"max_episode_steps": config["max_episode_steps"]} if "max_episode_steps" in config else {}
    try:
        return make_task(config["task"], **steps)
    except UserError:  # a task this process cannot build (an unregistered custom one): no section
        return None


def _outcomes(layout: RunLayout) -> dict[str, dict[int, dict[str, Any]]]:
    """``{method label: {seed: {"success": bool}}}`` from MDM, MDI and the benchmark's DAgger."""
    outcomes: dict[str, dict[int, dict[str, Any]]] = {}
    if layout.eval_table("mdm").is_file():
        table = by_method(read_csv(layout.eval_table("mdm")))
        for m in method_order(table):
            outcomes[f"MDM {method_label(m)}" if m != "bc" else "BC"] = table[m]
    if layout.eval_table("mdi").is_file():
        table = by_method(read_csv(layout.eval_table("mdi")))
        for m in method_order(table):
            outcomes[f"{method_label(m)}, one shot"] = {
                s: {"success": r["one_shot_success"]} for s, r in table[m].items()
            }
    if layout.benchmark_table.is_file():
        dagger = [r for r in read_csv(layout.benchmark_table) if r["method"] == "dagger"]
        if dagger:
            rounds = max(int(r["setting"]) for r in dagger)
            outcomes[f"DAgger, {rounds} round{'s' * (rounds != 1)}"] = {
                r["seed"]: r for r in dagger if int(r["setting"]) == rounds
            }
    return outcomes


def _seeds(count: int) -> str:
    return f"{count} seed{'s' * (count != 1)}"


def _mark(row: dict[str, Any] | None) -> str:
    if row is None:
        return "-"
    return "✓" if row["success"] else "✗"


def _figure(outcomes: dict[str, dict[int, dict[str, Any]]], sizes: dict[int, float], path: Path) -> Path:
    methods = list(outcomes)
    fig, ax = plt.subplots(figsize=(7.5, 0.45 * len(methods) + 1.2), layout="constrained")
    for row, method in enumerate(methods):
        seeds = sorted(outcomes[method])
        ok = [s for s in seeds if outcomes[method][s]["success"]]
        failed = [s for s in seeds if not outcomes[method][s]["success"]]
        ax.scatter([sizes[s] for s in ok], [row] * len(ok), s=22, color="C0")
        ax.scatter([sizes[s] for s in failed], [row] * len(failed), s=22, facecolors="none", edgecolors="C3")
    ax.set_yticks(range(len(methods)), methods)
    ax.invert_yaxis()
    ax.set_xlabel("variation size")
    return save_figure(fig, path)
