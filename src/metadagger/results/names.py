"""How a findings line names what it reads: a method with the share of the demonstration it
starts from, a reference (a control, BC refitted, a constant twin) by its short name, and a paired
difference in points with its interval."""

from __future__ import annotations

from typing import Any

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import BC_REFIT, metal_family, metal_twins

#: The controls, by benchmark method: zero-query heads every mapper must beat.
CONTROLS = ("mdm-pistar-head", "mdm-mean-da")

#: The references by the short names the findings' lines use.
SHORT_NAMES = {CONTROLS[0]: "pi*'s head", CONTROLS[1]: "mean-DA", BC_REFIT: "BC refitted", "dagger": "DAgger"}


def short_label(method: str) -> str:
    """A method's name in a findings line: a reference's short name, else its label."""
    return SHORT_NAMES.get(method, method_label(method))


#: A constant twin by the head in the mapper's place.
TWIN_NAMES = {"mean-da": "mean-DA", "pistar-head": "pi*-head", "zero": "zero-head"}


def reference_label(method: str, against: str, fraction: float) -> str:
    """What ``method`` was compared with, as a findings line names it: a constant twin of it (one
    that is not a control itself) as ``its mean-DA twin``, any other reference by its short name."""
    family = metal_family(against)
    if against not in SHORT_NAMES and against in metal_twins(method) and family is not None:
        return f"its {TWIN_NAMES.get(family[1], family[1])} twin"
    return with_share(short_label(against), fraction)


def with_share(label: str, share: float) -> str:
    """A method's name with the share of the demonstration it starts from, where that is not all of
    it: ``MDM Ridge (50% of the demonstration)``."""
    return label if float(share) == 1.0 else f"{label} ({float(share):.0%} of the demonstration)"


def difference_points(comparison: dict[str, Any]) -> str:
    """A paired difference in points with its 95% interval: ``+5 (-3 to +13)`` (where it shows, the unit is said
    once: a findings page's "How to read a claim", a table's note)."""
    return (
        f"{100 * comparison['difference']:+.0f} ({100 * comparison['ci_low']:+.0f} to "
        f"{100 * comparison['ci_high']:+.0f})"
    )
