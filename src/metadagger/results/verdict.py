"""The ``verdict`` block: does a MetaL DAgger method beat every one of its references at equal queries?

Each run's benchmark rows (``queries.csv``) read every MetaL DAgger curve that reads a learned mapper against its
references, on the same seeds and at the same spend: its constant twins (the same method with a
control's head, or zero, in the mapper's place), BC refitted, DART where it ran, and the best gate; at each budget and
by the area under the curve (:func:`~metadagger.evaluation.benchmark.summary.budget_reading`). A
curve beats its references at a reading when every one of those paired 95% intervals lies above 0
there. For each run, on its unseen seeds and (in an item nested under the run's) on its
confirmation seeds where it has them, the block names every reading where a curve does, or says
that none does and gives the closest: the reading whose lowest lower bound over the references is
highest. A run with both seed sets, where a curve beats every reference on either, gets a third
item: the readings where one does on both sets, the same curve at the same budget (or by area), or
that there is none, so that nothing is claimed from one set alone.
"""

from __future__ import annotations

from typing import Any

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.paired import smallest_shown_difference
from metadagger.results.names import difference_points, reference_label, with_share
from metadagger.results.tables import SEED_SETS, BlockContext, missing_run, rows_reading, run_names, seed_set_item

Curve = tuple[str, float]


def verdict(context: BlockContext, names: str = "") -> str:
    """One item per run of ``names`` (comma-separated; default every canonical run, the paper presets
    first) and seed set: where a MetaL DAgger method beats all its references, or that none does
    and the closest."""
    lines = []
    for name in run_names(names):
        found = context.runs.get(name)
        if found is None:
            lines.append(f"- `{name}`: {missing_run(name)}")
            continue
        above = []
        for seeds, folder in SEED_SETS:
            if found.path(f"{folder}/queries.csv").is_file():
                text, beats = _judged(rows_reading(found.path(f"{folder}/queries.csv")), seeds)
                lines.append(seed_set_item(context, found, first=not above, named=text))
                above.append(beats)
        if len(above) == 2 and any(above):  # where neither set has one, its two lines say so
            lines.append(seed_set_item(context, found, first=False, named=_on_both(*above)))
    return "\n".join(lines)


Reading = tuple[Curve, str]
"""A curve at one reading: a budget (``+5%``) or ``area``."""


def _on_both(unseen: list[Reading], confirmation: list[Reading]) -> str:
    """The readings above every reference on both seed sets, or that there is none."""
    both = [key for key in unseen if key in confirmation]
    if not both:
        return "both seed sets: no method is above all its references at the same reading on both, so none is claimed."
    return "both seed sets: above every one of its references on both: " + "; ".join(_place(k) for k in both) + "."


def _judged(reading: dict[str, Any] | None, seeds: str) -> tuple[str, list[Reading]]:
    """The verdict on one seed set's equal-budget reading, and the readings above all references."""
    if not reading:
        return f"{seeds}: no DAgger rows, so no equal-budget reading.", []
    readings = [(f"+{b['share']:.0%}", b["metal"]) for b in reading["budgets"]] + [("area", reading["auc_metal"])]
    groups: dict[Reading, list[dict[str, Any]]] = {}
    for where, comparisons in readings:
        for c in comparisons:
            groups.setdefault(((c["method"], float(c["demo_fraction"])), where), []).append(c)
    floor = smallest_shown_difference(len(reading["seeds"]))
    shows = "no difference can show" if floor is None else f"a difference shows from {100 * floor:.0f} points"
    head = f"{len(reading['seeds'])} {seeds} ({shows})"
    if not groups:
        return f"{head}: no method that reads a learned mapper ran.", []
    above = [key for key, comparisons in groups.items() if all(c["ci_low"] > 0 for c in comparisons)]
    if above:
        text = "; ".join(_reading(k, groups[k]) for k in above)
        return f"{head}: above every one of its references: {text}.", above
    closest = max(groups, key=lambda key: min(c["ci_low"] for c in groups[key]))
    closest_reading = _reading(closest, groups[closest])
    return f"{head}: none above all its references; closest: {closest_reading}.", []


def _place(key: Reading) -> str:
    """A curve at a reading, as a line names it: ``MDM Ridge at demonstration +5%``."""
    (method, fraction), where = key
    return with_share(method_label(method), fraction) + (
        " by area" if where == "area" else f" at demonstration {where}"
    )


def _reading(key: Reading, comparisons: list[dict[str, Any]]) -> str:
    """A curve at a reading against each reference; references with the same interval share one."""
    groups: dict[str, list[str]] = {}
    for c in comparisons:
        groups.setdefault(difference_points(c), []).append(_against(c))
    parts = [
        f"against {names[0]} {numbers}" if len(names) == 1 else f"against {_listed(names)}, each {numbers}"
        for numbers, names in groups.items()
    ]
    return f"{_place(key)}, " + ", ".join(parts)


def _listed(names: list[str]) -> str:
    return ", ".join(names[:-1]) + " and " + names[-1]


def _against(comparison: dict[str, Any]) -> str:
    return reference_label(comparison["method"], comparison["against"], comparison["against_demo_fraction"])
