"""Every gate, declared once: what it is called, how reports label it, its default sweep and options.

A :class:`GateDeclaration` is all that the benchmark, its configs, the command line's help, the
reports, the figure and the results registry read of a gate. Gates come from two places: the
built-in ones below, and installed packages that declare an entry point in the group
``metadagger.gates`` naming a declaration (``lazy = "mypkg.gates:LAZY"``), loaded on first use.
A broken plug-in is one :class:`~metadagger.errors.UserError` naming its package. docs/benchmark.md
("Adding a gate") walks through a plug-in; ``examples/lazydagger`` is one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Iterable

from metadagger.errors import UserError
from metadagger.imitation.gates import EnsembleGate, Gate, NoveltyGate, RandomGate, SafeGate
from metadagger.imitation.memory_gates import ConformalGate, ThriftyGate
from metadagger.imitation.reading_gates import OracleGate
from metadagger.imitation.uncertainty_gates import EntropyGate, LeastConfidenceGate, MarginGate
from metadagger.utils.plugins import load_plugins

#: Entry-point group through which installed packages add gates.
ENTRY_POINT_GROUP = "metadagger.gates"
#: A gated method's name in ``benchmark.methods``: ``dagger-<gate>``.
GATED_PREFIX = "dagger-"


@dataclass(frozen=True)
class GateDeclaration:
    """One gate as the benchmark knows it."""

    name: str
    """Its name: the benchmark method ``dagger-<name>`` runs it."""
    gate: type[Gate]
    """The :class:`~metadagger.imitation.gates.Gate` subclass; its ``setting`` field takes the sweep's values."""
    label: str
    """How tables and figures name the method, e.g. ``DAgger, LazyDAgger gate``."""
    grid: tuple[float, ...]
    """The default sweep of its setting (``benchmark.grids`` overrides it), fixed before any benchmark ran."""
    summary: str
    """One line for help texts and docs: what it asks about, and where it comes from."""
    shared: dict[str, str] = field(default_factory=dict)
    """Gate fields set from the benchmark's shared options: ``{field: option}``, e.g. ``{"K": "ensemble_heads"}``."""
    reference: bool = False
    """A reference drawn beside the methods and never ranked among them (the oracle: the learner's-mistakes rule)."""

    def __post_init__(self) -> None:
        where = f"gate declaration {self.name!r}"
        if not self.name or self.name != self.name.strip().lower() or " " in self.name or "," in self.name:
            raise UserError(f"{where}: the name must be non-empty, lower case, without spaces or commas")
        if not (isinstance(self.gate, type) and issubclass(self.gate, Gate)) or not hasattr(self.gate, "setting"):
            raise UserError(
                f"{where}: gate must be a Gate subclass with a `setting` class attribute, got {self.gate!r}"
            )
        if self.gate.reads_expert and not self.reference:
            raise UserError(f"{where}: a gate that reads the expert's labels can only be a reference (reference=True)")
        if self.gate.reads_reference:
            raise UserError(
                f"{where}: {self.gate.__name__} reads a reference head, which the benchmark hands only to MetaL "
                "DAgger's disagreement methods (disagree-<kind>); read the learner's own view.head and view.outputs "
                "instead, and drop reads_reference"
            )
        if not self.grid:
            raise UserError(f"{where}: the default grid must not be empty")
        fields = {f.name for f in dataclasses.fields(self.gate)}
        unknown = sorted(set(self.shared) - fields)
        if unknown:
            raise UserError(f"{where}: shared option(s) for unknown gate field(s) {unknown}; fields: {sorted(fields)}")

    @property
    def method(self) -> str:
        """The benchmark method that runs the gate: ``dagger-<name>``."""
        return GATED_PREFIX + self.name


_BUILT_IN = (
    GateDeclaration(
        "random",
        RandomGate,
        "DAgger, random gate",
        (0.05, 0.2, 0.5),
        "each visited state with probability p: the matched-budget control",
    ),
    GateDeclaration(
        "ensemble",
        EnsembleGate,
        "DAgger, ensemble gate",
        (0.5, 0.8, 0.95),
        "disagreement of K bootstrap ridge heads, above a quantile",
        shared={"K": "ensemble_heads"},
    ),
    GateDeclaration(
        "safe",
        SafeGate,
        "DAgger, SafeDAgger gate",
        (0.5, 0.8, 0.95),
        "SafeDAgger: a ridge estimate that the learner's action differs from the expert's, above a quantile",
    ),
    GateDeclaration(
        "novelty",
        NoveltyGate,
        "DAgger, novelty gate",
        (0.5, 0.8, 0.95),
        "distance to the k-th nearest labelled state, above a quantile",
        shared={"k": "novelty_k"},
    ),
    GateDeclaration(
        "least-confidence",
        LeastConfidenceGate,
        "DAgger, least-confidence gate",
        (0.5, 0.8, 0.95),
        "uncertainty sampling: 1 - the learner's largest class probability, above a quantile (classes only)",
    ),
    GateDeclaration(
        "margin",
        MarginGate,
        "DAgger, margin gate",
        (0.5, 0.8, 0.95),
        "uncertainty sampling: 1 - the gap between the learner's two likeliest classes, above a quantile "
        "(classes only)",
    ),
    GateDeclaration(
        "entropy",
        EntropyGate,
        "DAgger, entropy gate",
        (0.5, 0.8, 0.95),
        "uncertainty sampling: the entropy of the learner's class distribution, above a quantile (classes only)",
    ),
    GateDeclaration(
        "thrifty",
        ThriftyGate,
        "DAgger, ThriftyDAgger gate",
        (0.025, 0.1, 0.25),
        "ThriftyDAgger: novel (ensemble variance) or risky (estimated failure), each at a target rate",
        shared={"K": "ensemble_heads"},
    ),
    GateDeclaration(
        "conformal",
        ConformalGate,
        "DAgger, conformal gate",
        (0.05, 0.2, 0.5),
        "CRSAIL: neighbour distance above a threshold calibrated once at miscoverage alpha",
        shared={"k": "novelty_k"},
    ),
    GateDeclaration(
        "oracle",
        OracleGate,
        "Oracle: the learner's-mistakes rule (reference)",
        (0.5, 0.8, 0.95),
        "a reference, not a method and not a ceiling: the states where the learner's action differs from the "
        "expert's (gates can do better)",
        reference=True,
    ),
)

_GATES: dict[str, GateDeclaration] = {d.name: d for d in _BUILT_IN}
_plugins_loaded = False


def register_gate(declaration: GateDeclaration) -> GateDeclaration:
    """Make a gate known everywhere (configs, the benchmark, reports, the command line); returns it."""
    _GATES[declaration.name] = declaration
    return declaration


def _load_plugins() -> None:
    """Register the gates of installed packages (group ``metadagger.gates``), once they all load: a
    broken one is named again by every later call, never left out in silence."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    for declaration in load_plugins(
        ENTRY_POINT_GROUP, plugin="gate", thing="gate", expected=GateDeclaration, known=_GATES
    ):
        register_gate(declaration)
    _plugins_loaded = True


def gate_declarations() -> dict[str, GateDeclaration]:
    """Every gate by name: the built-in ones, then those registered or installed."""
    _load_plugins()
    return dict(_GATES)


def get_gate(name: str) -> GateDeclaration:
    """The gate called ``name``; an unknown name is a :class:`UserError` listing the known ones."""
    gates = gate_declarations()
    if name not in gates:
        raise UserError(f"unknown gate {name!r}: expected one of {', '.join(gates)}")
    return gates[name]


def gated_names() -> list[str]:
    """The gates that are methods (every gate but the references), by name."""
    return [name for name, d in gate_declarations().items() if not d.reference]


def gate_of_method(method: str) -> GateDeclaration:
    """The gate a gated method ``dagger-<gate>`` runs; an unknown one is a :class:`UserError`."""
    gates = {d.method: d for d in gate_declarations().values()}
    if method not in gates:
        raise UserError(
            f"unknown gated method {method!r}: expected one of {', '.join(gates)}; a gate added by register_gate in "
            "one process is not known to worker processes: declare it as an entry point (docs/benchmark.md, "
            "'Adding a gate') or run with --executor inline"
        )
    return gates[method]


def check_gates_serve(methods: Iterable[str], *, discrete: bool, task: str) -> None:
    """A :class:`UserError` naming the gated ``methods`` that read the learner's class distribution
    when ``task`` acts with action vectors (not ``discrete``), and the gates that do serve it."""
    if discrete:
        return
    gates = gate_declarations()
    refused = [m for m in methods if m.startswith(GATED_PREFIX) and m in {d.method for d in gates.values()}]
    refused = [m for m in refused if gate_of_method(m).gate.needs_classes]
    if refused:
        serving = [d.method for d in gates.values() if not d.gate.needs_classes and not d.reference]
        raise UserError(
            f"benchmark method(s) {', '.join(refused)} read the learner's class distribution, but task {task} acts "
            f"with action vectors; drop them, or use a gate that serves it: {', '.join(serving)}"
        )


def built_in_grids(*, every_task: bool = False) -> dict[str, list[float]]:
    """The default sweeps of the built-in gates that are methods, by method (``benchmark.grids``'s
    default); ``every_task``: of those that serve every task alone (none that reads a class distribution)."""
    return {d.method: list(d.grid) for d in _BUILT_IN if not d.reference and not (every_task and d.gate.needs_classes)}


def make_gate(name: str, setting: float, **options: Any) -> Gate:
    """The gate called ``name`` at one value of its sweep.

    Args:
        name: a gate's name (:func:`gate_declarations`).
        setting: the value of the gate's ``setting`` field (``p`` for ``random``, ``rate`` for
            ``thrifty``, ``alpha`` for ``conformal``, ``quantile`` for the others).
        **options: the gate's other fields, left at their defaults when not given.

    Returns:
        The gate.
    """
    cls = get_gate(name).gate
    allowed = [f.name for f in dataclasses.fields(cls) if f.name != cls.setting]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise UserError(
            f"unknown option(s) {', '.join(unknown)} for gate {name!r}: expected {', '.join(allowed) or 'none'}"
        )
    return cls(**{cls.setting: setting}, **options)
