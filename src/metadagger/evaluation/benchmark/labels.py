"""How tables, figures and reports name a benchmark method, and the order they list methods in."""

from __future__ import annotations

from typing import Iterable

from metadagger.evaluation.benchmark.methods import (
    DISAGREE_PREFIX,
    GATED_PRIOR,
    MDI_LABELS,
    PRIOR_DAGGER_PREFIX,
    PRIOR_PREFIX,
    benchmark_methods,
)
from metadagger.mapping.priors import ZERO
from metadagger.mapping.registry import get_kind, kind_names


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
