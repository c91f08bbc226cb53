"""Every method the query benchmark compares, declared once: a typed key per row.

A row of ``benchmark/queries.csv`` is one method at one setting, from one share of the
demonstration, on one seed. The key of that method and setting is a :class:`MethodKey` built by
the method's entry in :data:`METHODS`, never parsed back from text: its subclasses carry what the
method needs (the mapper kind, the DAgger round, the gate and its value, the MDI test), and
:func:`with_demo_fractions` adds the keys of the methods that start from a shorter
demonstration. ``MethodKey.id`` names its rows in the run's logs and stamps; it is written, never
read back into a key.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Sequence

from metadagger.imitation.gates import GATES
from metadagger.mapping.registry import control_names

#: Prefix of the MDM methods: ``mdm-<mapper kind>``.
MDM_PREFIX = "mdm-"
#: The control that refits w_BC as DAgger does, with no new label.
BC_REFIT = "bc-refit"
#: The MDI protocol's methods (:mod:`metadagger.evaluation.mdi`) and their names in the benchmark,
#: where ``dagger`` (DAgger from a Xavier head) must not be confused with the pairs' DAgger.
MDI_METHODS = {"dagger-mdi": "dagger-mdi", "dagger-bc": "dagger-bc-init", "dagger": "dagger-xavier"}
#: The MDI protocol's two tests and their settings in the benchmark.
MDI_SHOTS = {"oneshot": "one-shot", "twoshot": "two-shot"}


@dataclass(frozen=True)
class MethodKey:
    """One method at one setting, as its rows name them (``method``, ``setting`` columns)."""

    method: str
    setting: str
    demo_fraction: float = field(default=1.0, kw_only=True)
    """The share of the demonstration's steps the method starts from (BC on its first steps)."""

    @property
    def id(self) -> str:
        """The name of its rows in the run's logs and stamps (written, never parsed)."""
        full = f"{self.method}@{self.setting}"
        return full if self.demo_fraction == 1.0 else f"{full}@demo{self.demo_fraction:g}"


@dataclass(frozen=True)
class MapperKey(MethodKey):
    """MDM: a mapper kind's head for w_BC, used as it is."""

    kind: str


@dataclass(frozen=True)
class RoundKey(MethodKey):
    """Plain DAgger after ``round`` rounds (every visited state labelled)."""

    round: int


@dataclass(frozen=True)
class RefitKey(MethodKey):
    """w_BC refitted ``rounds`` times on the demonstration alone: DAgger's training, no new label."""

    rounds: int


@dataclass(frozen=True)
class GateKey(MethodKey):
    """Gated DAgger after every round, its gate at one value of its sweep."""

    gate: str
    value: float


@dataclass(frozen=True)
class ShotKey(MethodKey):
    """One MDI method (Table 6) at one of its tests."""

    mdi_method: str
    shot: str


def bc_keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    """w_BC rolled out: the demonstration's queries only."""
    return [MethodKey("bc", "")]


def mdm_keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    """Every mapper kind (and control) applied to w_BC."""
    return [MapperKey(MDM_PREFIX + kind, "", kind=kind) for kind in kinds]


def dagger_keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    """The pairs' DAgger after each of its rounds."""
    return [RoundKey("dagger", str(r), round=r) for r in range(1, rounds + 1)]


def bc_refit_keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    """The control for how much of DAgger's gain is training, not labels: w_BC refitted as often
    and as long as DAgger refits it, on the demonstration alone."""
    return [RefitKey(BC_REFIT, str(rounds), rounds=rounds)]


def gate_keys(gate: str) -> Callable[[int, tuple[str, ...], dict[str, list[float]], bool], list[MethodKey]]:
    """DAgger gated by ``gate``, after the last round, at each value of its grid."""

    def keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
        method = f"dagger-{gate}"
        return [GateKey(method, f"{value:g}", gate=gate, value=float(value)) for value in grids[method]]

    return keys


def mdi_keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    """Table 6's one- and two-shot tests of DAgger-MDI, DAgger-BC and DAgger (runs with an mdi section)."""
    if not mdi:
        return []
    return [
        ShotKey(name, setting, mdi_method=method, shot=shot)
        for method, name in MDI_METHODS.items()
        for shot, setting in MDI_SHOTS.items()
    ]


#: Every benchmark method by its name in ``benchmark.methods``: the keys of its rows, given the
#: pairs' DAgger rounds, the MDM mapper kinds, the gate grids and whether the run has MDI.
METHODS: dict[str, Callable[[int, tuple[str, ...], dict[str, list[float]], bool], list[MethodKey]]] = {
    "bc": bc_keys,
    "mdm": mdm_keys,
    "dagger": dagger_keys,
    BC_REFIT: bc_refit_keys,
    **{f"dagger-{gate}": gate_keys(gate) for gate in GATES},
    "mdi": mdi_keys,
}
#: The gated methods and the gate each one uses.
GATED = {f"dagger-{gate}": gate for gate in GATES}


def reads_demonstration(key: MethodKey) -> bool:
    """Whether the method's head depends on the demonstration: every method but the MDM controls
    (pi*'s head, mean-DA), which ask the expert nothing and are charged no query."""
    return not (isinstance(key, MapperKey) and key.kind in control_names())


def starts_from_demonstration(key: MethodKey) -> bool:
    """Whether the method also runs from a shorter demonstration: BC, the learned MDM kinds and the
    gated DAgger settings (plain DAgger and MDI keep the whole one, the reference they are read against)."""
    return (
        (type(key) is MethodKey and key.method == "bc")
        or isinstance(key, GateKey)
        or (isinstance(key, MapperKey) and reads_demonstration(key))
    )


def with_demo_fractions(keys: Sequence[MethodKey], fractions: Sequence[float]) -> list[MethodKey]:
    """``keys`` (each on the whole demonstration), each followed by its keys on every shorter
    share in ``fractions`` (ascending) where :func:`starts_from_demonstration`."""
    shorter = sorted(f for f in fractions if f < 1.0)
    return [
        k
        for key in keys
        for k in (key, *(dataclasses.replace(key, demo_fraction=f) for f in shorter if starts_from_demonstration(key)))
    ]
