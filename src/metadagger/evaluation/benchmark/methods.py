"""Every method the query benchmark compares, declared once, and a typed key per row.

A benchmark method is a :class:`BenchmarkMethod`: its name in ``benchmark.methods``, its label,
one doc line and the keys of its rows. The built-in ones are below; every gate of
:mod:`metadagger.imitation.gate_registry` (plug-ins included) adds ``dagger-<gate>``. Every list,
label and help text of the benchmark is read from :func:`benchmark_methods`.

A row of ``benchmark/queries.csv`` is one method at one setting, from one share of the
demonstration, on one seed. The key of that method and setting is a :class:`MethodKey`, never
parsed back from text: its subclasses carry what the method needs (the mapper kind, the DAgger
round, the gate and its value, the MDI test) and what differs per method (which chain of
rollouts makes its row, what its rows are stamped with, whether it reads the demonstration).
``MethodKey.id`` names its rows in the run's logs and stamps; it is written, never read back.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.coverage import VARIANCE_SHARE
from metadagger.evaluation.mdi import MDI_METHODS
from metadagger.imitation.gate_registry import GATED_PREFIX, gate_declarations
from metadagger.mapping.priors import ZERO
from metadagger.mapping.registry import control_names

#: Prefix of the MDM methods: ``mdm-<mapper kind>``.
MDM_PREFIX = "mdm-"
#: Prefix of BC with a prior (:mod:`metadagger.mapping.priors`): ``prior-<mapper kind>``, ``prior-zero``.
PRIOR_PREFIX = "prior-"
#: Prefix of DAgger with a prior in every fit: ``prior-dagger-<mapper kind>``, ``prior-dagger-zero``.
PRIOR_DAGGER_PREFIX = "prior-dagger-"
#: Between a gated method and its prior's mean in a gated method with a prior: ``dagger-<gate>+prior-<mean>``.
GATED_PRIOR = "+prior-"
#: Prefix of DAgger with the disagreement gate (:class:`~metadagger.imitation.reading_gates.DisagreementGate`)
#: against a mapper kind's head: ``disagree-<mapper kind>``.
DISAGREE_PREFIX = "disagree-"
#: The benchmark methods whose fits carry a prior (the stage builds their priors from the pairs).
PRIOR_METHODS = ("prior", "prior-dagger", "prior-gated")
#: The disagreement gate's default sweep: the score gates' quantiles (labels about 50%, 20%, 5%).
DISAGREE_GRID = (0.5, 0.8, 0.95)
#: The control that refits w_BC as DAgger does, with no new label.
BC_REFIT = "bc-refit"
#: The control that spends DAgger's labels on more demonstrations, perturbed (DART).
DART = "dart"
#: The MDI protocol's two tests and their settings in the benchmark.
MDI_SHOTS = {"oneshot": "one-shot", "twoshot": "two-shot"}
#: The mapper kind of the MDI rows: whichever the run's ``mdi.mapper`` names.
MDI_MAPPER = "mdi"


@dataclass(frozen=True)
class StampInputs:
    """What a key's own stamp may read of the run: its gate's options, the MDI protocol's settings."""

    gate_options: Callable[[str], dict[str, Any]]
    """A gated method's gate options."""
    mdi: dict[str, Any] | None
    """The MDI protocol's settings as stamped, where the run has one."""
    priors: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Each prior's strength and precision as stamped, by its mean (a mapper kind or ``zero``)."""
    dart_noise: float | None = None
    """DART's perturbation (``benchmark.dart_noise``)."""


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

    @property
    def chain(self) -> str:
        """Which chain of rollouts makes its row: keys that share one are made by one chain."""
        return self.id

    @property
    def reads_demonstration(self) -> bool:
        """Whether its head depends on the demonstration (its queries are charged)."""
        return True

    @property
    def starts_from_demonstration(self) -> bool:
        """Whether it also runs from a shorter demonstration (``benchmark.demo_fractions``)."""
        return False

    @property
    def mapper_kind(self) -> str | None:
        """The mapper kind whose file its rows read, if any."""
        return None

    @property
    def prior_mean(self) -> str | None:
        """The mean of the prior its fits carry (a mapper kind or ``zero``), if any."""
        return None

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        """What its rows are made from beyond what every row shares; a mapper's fingerprint is added by the caller."""
        return {} if self.demo_fraction == 1.0 else {"demo_fraction": self.demo_fraction}


@dataclass(frozen=True)
class BCKey(MethodKey):
    """w_BC rolled out."""

    @property
    def starts_from_demonstration(self) -> bool:
        return True


@dataclass(frozen=True)
class MapperKey(MethodKey):
    """MDM: a mapper kind's head for w_BC, used as it is."""

    kind: str

    @property
    def reads_demonstration(self) -> bool:
        # the controls (pi*'s head, mean-DA) ask the expert nothing and are charged no query
        return self.kind not in control_names()

    @property
    def starts_from_demonstration(self) -> bool:
        return self.reads_demonstration

    @property
    def mapper_kind(self) -> str | None:
        return self.kind

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        charged = {} if self.reads_demonstration else {"charged": "no query"}
        return {**super().own_stamp(inputs), **charged}


class TowardMean:
    """What a key whose fits carry a prior (its ``mean``: a mapper kind, or ``zero``) reads and stamps."""

    mean: str

    @property
    def mapper_kind(self) -> str | None:
        return None if self.mean == ZERO else self.mean

    @property
    def prior_mean(self) -> str | None:
        return self.mean

    def prior_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        """The prior's strength and precision as the run stamped them."""
        return {"prior": inputs.priors[self.mean]}


@dataclass(frozen=True)
class PriorKey(TowardMean, MethodKey):
    """BC on the demonstration with a Gaussian prior on the head, toward a mapper kind's head for
    w_BC (``zero``: toward the zero head), its strength chosen on the validation pairs."""

    mean: str

    @property
    def starts_from_demonstration(self) -> bool:
        return True

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        return {**super().own_stamp(inputs), **self.prior_stamp(inputs)}


@dataclass(frozen=True)
class PriorRoundKey(PriorKey):
    """DAgger after ``round`` rounds (every visited state labelled) from BC with a prior, the same
    prior in every round's refit (its mean a mapper kind's head for w_BC, or ``zero``)."""

    round: int

    @property
    def chain(self) -> str:
        return f"{self.method}@demo{self.demo_fraction:g}"  # one chain makes every round's row

    @property
    def starts_from_demonstration(self) -> bool:
        return False


@dataclass(frozen=True)
class RoundKey(MethodKey):
    """Plain DAgger after ``round`` rounds (every visited state labelled)."""

    round: int

    @property
    def chain(self) -> str:
        return f"{self.method}@demo{self.demo_fraction:g}"  # one chain makes every round's row

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        # its rows carry the coverage gap of the states visited so far (evaluation/benchmark/coverage.py)
        return {**super().own_stamp(inputs), "coverage_share": VARIANCE_SHARE}


@dataclass(frozen=True)
class DartKey(MethodKey):
    """DART at plain DAgger's cumulative labels after ``round`` rounds: the expert's perturbed
    episodes of the seed labelled up to that budget, w_BC refitted on them and the demonstration
    (a control: more demonstrations instead of labels on the learner's states)."""

    round: int

    @property
    def chain(self) -> str:
        return f"dagger@demo{self.demo_fraction:g}"  # made by DAgger's chain, which knows its budgets

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        return {**super().own_stamp(inputs), "dart_noise": inputs.dart_noise}


@dataclass(frozen=True)
class RefitKey(MethodKey):
    """w_BC refitted ``rounds`` times on the demonstration alone: DAgger's training, no new label."""

    rounds: int


@dataclass(frozen=True)
class GateKey(MethodKey):
    """Gated DAgger after every round, its gate at one value of its sweep."""

    gate: str
    value: float

    @property
    def starts_from_demonstration(self) -> bool:
        return True

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        return {**super().own_stamp(inputs), "gate": inputs.gate_options(self.method)}


@dataclass(frozen=True)
class PriorGateKey(TowardMean, GateKey):
    """Gated DAgger after every round, its gate at one value, from BC with a prior and the same prior
    in every round's refit (its mean a mapper kind's head for w_BC, or ``zero``)."""

    mean: str

    @property
    def starts_from_demonstration(self) -> bool:
        return False

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        gate = inputs.gate_options(GATED_PREFIX + self.gate)
        return {**MethodKey.own_stamp(self, inputs), "gate": gate, **self.prior_stamp(inputs)}


@dataclass(frozen=True)
class DisagreeKey(MethodKey):
    """DAgger from w_BC after every round, labelling where a mapper kind's head for w_BC and the
    current head act apart (:class:`~metadagger.imitation.reading_gates.DisagreementGate` at ``value``)."""

    kind: str
    value: float

    @property
    def mapper_kind(self) -> str | None:
        return self.kind

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        return {**super().own_stamp(inputs), "gate": "disagree"}


@dataclass(frozen=True)
class ShotKey(MethodKey):
    """One MDI method (Table 6) at one of its tests; made by the MDI protocol, not by a chain."""

    shot: str

    @property
    def mapper_kind(self) -> str | None:
        return MDI_MAPPER

    def own_stamp(self, inputs: StampInputs) -> dict[str, Any]:
        return {} if inputs.mdi is None else {"mdi": inputs.mdi}


KeyMaker = Callable[[int, tuple[str, ...], dict[str, list[float]], bool], list[MethodKey]]
"""``keys(rounds, mapper kinds, grids by method, has mdi) -> the method's keys``."""


@dataclass(frozen=True)
class BenchmarkMethod:
    """One benchmark method as configs, help texts, reports and figures know it."""

    name: str
    """Its name in ``benchmark.methods`` and the ``method`` column."""
    label: str
    """How tables and figures name it."""
    summary: str
    """One line for help texts and docs."""
    keys: KeyMaker
    """The keys of its rows on one seed."""
    reference: bool = False
    """A reference (the oracle, the learner's-mistakes rule): drawn and tabled beside the methods, never ranked."""


def _bc(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [BCKey("bc", "")]


def _mdm(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [MapperKey(MDM_PREFIX + kind, "", kind=kind) for kind in kinds]


def _prior(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [PriorKey(PRIOR_PREFIX + mean, "", mean=mean) for mean in (*kinds, ZERO)]


def _prior_dagger(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [
        PriorRoundKey(PRIOR_DAGGER_PREFIX + mean, str(r), mean=mean, round=r)
        for mean in (*kinds, ZERO)
        for r in range(1, rounds + 1)
    ]


def _prior_gated(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    gates = {d.method: d.name for d in gate_declarations().values() if not d.reference}
    return [
        PriorGateKey(method + GATED_PRIOR + mean, f"{value:g}", gate=gates[method], value=float(value), mean=mean)
        for method, grid in grids.items()
        if method in gates
        for mean in (*kinds, ZERO)
        for value in grid
    ]


def _disagree(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [DisagreeKey(DISAGREE_PREFIX + kind, f"{q:g}", kind=kind, value=q) for kind in kinds for q in DISAGREE_GRID]


def _dagger(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [RoundKey("dagger", str(r), round=r) for r in range(1, rounds + 1)]


def _dart(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [DartKey(DART, str(r), round=r) for r in range(1, rounds + 1)]


def _bc_refit(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    return [RefitKey(BC_REFIT, str(rounds), rounds=rounds)]


def _gated(gate: str) -> KeyMaker:
    def keys(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
        method = GATED_PREFIX + gate
        return [GateKey(method, f"{value:g}", gate=gate, value=float(value)) for value in grids[method]]

    return keys


def _mdi(rounds: int, kinds: tuple[str, ...], grids: dict[str, list[float]], mdi: bool) -> list[MethodKey]:
    if not mdi:
        return []
    return [ShotKey(method, setting, shot=shot) for method in MDI_METHODS for shot, setting in MDI_SHOTS.items()]


_BUILT_IN = (
    BenchmarkMethod("bc", "BC", "w_BC rolled out: the demonstration's queries only", _bc),
    BenchmarkMethod("mdm", "MDM", "every mapper kind of evaluate.methods (and control) applied to w_BC", _mdm),
    BenchmarkMethod("dagger", "DAgger", "the pairs' DAgger after each round, every visited state labelled", _dagger),
    BenchmarkMethod(
        BC_REFIT,
        "BC refitted as DAgger, no new label (control)",
        "w_BC refitted as often and as long as DAgger refits it, on the demonstration alone (a control)",
        _bc_refit,
    ),
    BenchmarkMethod(
        DART,
        "DART at DAgger's labels (control)",
        "the expert's episodes, executed action perturbed (benchmark.dart_noise), labelled up to DAgger's labels "
        "after each round, w_BC refitted on them as DAgger refits (a control; needs dagger)",
        _dart,
    ),
    BenchmarkMethod(
        "prior",
        "BC with a prior",
        "BC on the demonstration with a Gaussian prior toward each mapper kind's head (and zero), no further query",
        _prior,
    ),
    BenchmarkMethod(
        "prior-dagger",
        "DAgger with a prior",
        "DAgger from BC with a prior, the same Gaussian prior (toward each kind's head, and zero) in every refit",
        _prior_dagger,
    ),
    BenchmarkMethod(
        "prior-gated",
        "gated DAgger with a prior",
        "each gated method of the run at each setting, from BC with a prior and the prior in every refit, per mean",
        _prior_gated,
    ),
    BenchmarkMethod(
        "disagree",
        "DAgger, disagreement gate",
        "DAgger labelling where each mapper kind's head for w_BC and the current head act apart, above a quantile",
        _disagree,
    ),
)
_MDI = BenchmarkMethod(
    "mdi", "MDI", "Table 6's one- and two-shot tests of DAgger-MDI, DAgger-BC, DAgger (needs an mdi section)", _mdi
)
#: Labels of the MDI protocol's rows (its report's and the benchmark's).
MDI_LABELS = {"dagger-mdi": "DAgger-MDI", "dagger-bc-init": "DAgger-BC", "dagger-xavier": "DAgger from Xavier"}


def benchmark_methods() -> dict[str, BenchmarkMethod]:
    """Every benchmark method by name, in table order: the built-in ones, one per gate (plug-ins
    included), then ``mdi``."""
    gated = [
        BenchmarkMethod(d.method, d.label, d.summary, _gated(d.name), reference=d.reference)
        for d in gate_declarations().values()
    ]
    return {m.name: m for m in (*_BUILT_IN, *gated, _MDI)}


def gated_methods(*, references: bool = False) -> dict[str, str]:
    """The gated methods and the gate each runs; the reference ones (the oracle) only with ``references``."""
    return {d.method: d.name for d in gate_declarations().values() if references or not d.reference}


def reference_methods() -> tuple[str, ...]:
    """The methods that are references, never ranked: the oracle (the learner's-mistakes rule)."""
    return tuple(m.name for m in benchmark_methods().values() if m.reference)


def check_methods(names: Sequence[str], called: str) -> None:
    """Raise a :class:`UserError` naming the known methods unless every one of ``names`` is one."""
    known = benchmark_methods()
    unknown = [m for m in names if m not in known]
    if unknown:
        raise UserError(f"{called} has unknown method(s) {unknown}; allowed: {', '.join(known)}")


def with_demo_fractions(keys: Sequence[MethodKey], fractions: Sequence[float]) -> list[MethodKey]:
    """``keys`` (each on the whole demonstration), each followed by its keys on every shorter
    share in ``fractions`` (ascending) where it :attr:`~MethodKey.starts_from_demonstration`."""
    shorter = sorted(f for f in fractions if f < 1.0)
    return [
        k
        for key in keys
        for k in (key, *(dataclasses.replace(key, demo_fraction=f) for f in shorter if key.starts_from_demonstration))
    ]


def metal_family(method: str) -> tuple[str, str] | None:
    """A method that reads a mapper kind's head (or zero) as its family and that kind:
    ``prior-dagger-ridge`` -> (``prior-dagger-``, ``ridge``), ``dagger-safe+prior-zero`` ->
    (``dagger-safe+prior-``, ``zero``); None for any other method."""
    if GATED_PRIOR in method:
        gated, kind = method.split(GATED_PRIOR, 1)
        return gated + GATED_PRIOR, kind
    for prefix in (PRIOR_DAGGER_PREFIX, DISAGREE_PREFIX, PRIOR_PREFIX, MDM_PREFIX):  # the longer prefix first
        if method.startswith(prefix):
            return prefix, method.removeprefix(prefix)
    return None


def metal_twins(method: str) -> tuple[str, ...]:
    """The constant twins of a MetaL DAgger method that reads a learned mapper kind's head: the same
    method with each control's head (and, for the priors, zero) in the mapper's place; () for any
    other method. ``prior-ridge`` -> ``prior-mean-da``, ``prior-pistar-head``, ``prior-zero``;
    ``dagger-safe+prior-ridge`` -> ``dagger-safe+prior-mean-da``, ..."""
    found = metal_family(method)
    if found is None or found[1] == ZERO or found[1] in control_names():
        return ()
    family = found[0]
    with_zero = family in (PRIOR_PREFIX, PRIOR_DAGGER_PREFIX) or family.endswith(GATED_PRIOR)
    return tuple(family + c for c in (*control_names(), *((ZERO,) if with_zero else ())))
