"""The coverage figure: each unseen seed's coverage gap against a MetaL DAgger method's gain over
its constant twin (the area under the success-against-queries curve), one panel per method family.

A family is the methods of one kind of use of a mapper (MDM, BC with a prior, DAgger with a prior,
each gated DAgger with a prior, the disagreement gate); each learned kind is one colour, compared
with the family's mean-DA twin (its first twin where mean-DA did not run). Spearman's rho of each
kind is in the legend.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from metadagger.evaluation.benchmark.figure import PALETTE
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import (
    DISAGREE_PREFIX,
    GATED_PRIOR,
    MDM_PREFIX,
    PRIOR_DAGGER_PREFIX,
    PRIOR_PREFIX,
    metal_family,
)
from metadagger.mapping.priors import ZERO
from metadagger.mapping.registry import get_kind
from metadagger.utils.plotting import plt, save_figure

#: The families' titles by method prefix, one panel each (a gated method with a prior is titled by its gate).
FAMILIES = {
    PRIOR_DAGGER_PREFIX: "DAgger with a prior",
    PRIOR_PREFIX: "BC with a prior",
    DISAGREE_PREFIX: "disagreement gate",
    MDM_PREFIX: "MDM",
}
#: The twin each method is drawn against, where it ran.
PREFERRED_TWIN = "mean-da"


def _family(method: str) -> str:
    """A method's family: its prefix, or its gated method with a prior (``dagger-<gate>+prior-``)."""
    found = metal_family(method)
    assert found is not None, method  # the coverage reading holds MetaL methods alone
    return found[0]


def _family_title(family: str) -> str:
    if family.endswith(GATED_PRIOR):
        return f"{method_label(family.removesuffix(GATED_PRIOR))} with a prior"
    return FAMILIES[family]


def drawn_comparisons(coverage: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Per family, one comparison per method on the whole demonstration: against its mean-DA twin,
    else against its first twin that ran."""
    chosen: dict[str, dict[str, Any]] = {}
    for c in coverage["methods"]:
        if float(c["demo_fraction"]) != 1.0:
            continue
        preferred = _family(c["method"]) + PREFERRED_TWIN
        held = chosen.get(c["method"])
        if held is None or (c["against"] == preferred and held["against"] != preferred):
            chosen[c["method"]] = c
    families: dict[str, list[dict[str, Any]]] = {}
    for method, c in chosen.items():
        families.setdefault(_family(method), []).append(c)
    return families


def _kind_label(method: str) -> str:
    """The kind a method reads, as the registry names it (``zero`` as it is)."""
    kind = metal_family(method)[1]  # type: ignore[index]
    return kind if kind == ZERO else get_kind(kind).label


def draw_coverage(coverage: dict[str, Any]) -> Figure:
    """The figure of a summary's ``coverage`` reading (``coverage_reading`` in summary.py)."""
    families = drawn_comparisons(coverage)
    if not families:
        raise ValueError("no MetaL DAgger method with a learned mapper kind and a constant twin ran")
    columns = min(3, len(families))
    rows = math.ceil(len(families) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.6 * columns, 3.6 * rows), squeeze=False, sharey=True)
    for ax, (family, comparisons) in zip(axes.flat, families.items()):
        for index, c in enumerate(comparisons):
            rho = "n/a" if c["rho"] is None else f"{c['rho']:+.2f} (p {c['p_value']:.2f})"
            ax.scatter(
                coverage["gaps"],
                c["gains"],
                s=18,
                color=PALETTE[index % len(PALETTE)],
                label=f"{_kind_label(c['method'])}: rho {rho}",
                alpha=0.8,
            )
        ax.axhline(0.0, color="grey", linewidth=0.8)
        twin = _kind_label(comparisons[0]["against"])
        ax.set_title(f"{_family_title(family)}\nagainst its {twin} twin", fontsize="small")
        ax.legend(fontsize="x-small", frameon=False)
    for ax in list(axes.flat)[len(families) :]:
        ax.set_visible(False)
    fig.supxlabel(
        f"coverage gap: share of the energy of DAgger's states outside the directions of "
        f"{coverage['variance_share']:.0%} of the demonstration's feature variance",
        fontsize="small",
    )
    fig.supylabel("gain in area under the curve over the twin", fontsize="small")
    fig.tight_layout()
    return fig


def plot_coverage(coverage: dict[str, Any], path: Path) -> Path:
    """Draw :func:`draw_coverage` and save it as PNG at ``path``; the path written."""
    return save_figure(draw_coverage(coverage), path)


def has_twins(coverage: dict[str, Any] | None) -> bool:
    """Whether a coverage reading holds a comparison the figure draws."""
    return bool(coverage) and any(float(c["demo_fraction"]) == 1.0 for c in coverage["methods"])


__all__ = ["FAMILIES", "draw_coverage", "drawn_comparisons", "has_twins", "plot_coverage"]
