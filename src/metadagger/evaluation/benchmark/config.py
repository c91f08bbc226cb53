"""The benchmark's section of a run's config: which methods run, on which unseen seeds, with which gate grids."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.methods import (
    BC_REFIT,
    DART,
    benchmark_methods,
    check_methods,
    gated_methods,
    reference_methods,
)
from metadagger.imitation.gate_registry import built_in_grids, gate_of_method, get_gate, make_gate
from metadagger.imitation.lanes import check_lanes
from metadagger.utils.yaml_config import STAMPED_UNLESS_DEFAULT


@dataclass(frozen=True)
class BenchmarkConfig:
    """Which methods the benchmark runs, on which unseen seeds, with which gate grids."""

    RENAMED: ClassVar[dict[str, str]] = {"ceiling": "oracle"}
    """Keys of an older version's configs, by their names now (an error names the new one)."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or the pairs)."""
    confirm_seeds: tuple[int, ...] = ()
    """A second set of unseen seeds, fixed before any result is read, on which the same methods run
    again into ``benchmark/confirm/``: a reading chosen on the first set is checked on these."""
    methods: tuple[str, ...] = ("bc", "mdm", "dagger", BC_REFIT, *built_in_grids(every_task=True))
    """Benchmark methods (``metadagger config methods`` lists every one, plug-ins' included): ``bc``,
    ``mdm`` (every kind of ``evaluate.methods``), ``dagger``, ``bc-refit`` (w_BC refitted as DAgger
    refits it, on the demonstration alone: a control), the gated methods ``dagger-<gate>``, and
    ``mdi`` (the MDI protocol's methods; runs with an ``mdi`` section). The default holds every
    built-in gate that serves every task: the uncertainty gates, which read a class distribution,
    are named by the presets of tasks with classes."""
    grids: dict = field(default_factory=built_in_grids)
    """Each gated method's sweep (a gate left out sweeps its declared grid): the random share p;
    the score quantile above which a state is labelled (about 1 - quantile of each round's
    states); ThriftyDAgger's target rate of each of its two tests (their union labels at most
    twice it); the conformal gate's miscoverage (about that share of the first round's states).
    The defaults span label shares of about 50%, 20% and 5%, fixed before any benchmark ran (not
    tuned on any seeds)."""
    ensemble_heads: int = 5
    """K, the bootstrap heads of the ensemble and ThriftyDAgger gates."""
    novelty_k: int = 1
    """k, the neighbour of the novelty and conformal gates."""
    gate_options: dict = field(default_factory=dict, metadata=STAMPED_UNLESS_DEFAULT)
    """Further fields of a gate by method, e.g. ``{dagger-lazy: {low: 0.5}}`` (a plug-in's options)."""
    oracle: bool = True
    """Run the oracle rule (``dagger-oracle``) beside the methods: the learner's-mistakes rule, a
    reference that gates can beat, not a ceiling."""
    demo_fractions: tuple[float, ...] = (1.0,)
    """Shares of the demonstration's steps that BC, the learned MDM kinds and the gated settings
    start from, in (0, 1], 1 (the whole demonstration) among them; plain DAgger and MDI always
    start from the whole one."""
    dart_noise: float = field(default=0.2, metadata=STAMPED_UNLESS_DEFAULT)
    """DART's perturbation of the expert's executed action (method ``dart``): the probability of
    another class, drawn uniformly, with classes; the standard deviation of Gaussian noise on each
    coordinate with action vectors. Chosen per task on the pair seeds (docs/benchmark.md, "DART")."""
    held_out_every: int = field(default=0, metadata=STAMPED_UNLESS_DEFAULT)
    """0: none. k >= 2: every k-th step of each seed's demonstration (steps k-1, 2k-1, ...) is held
    out of every fit and every query count of the seed, and BC's and plain DAgger's rows record
    their head's mean loss on those expert states (``expert_loss``): whether BC fits the expert
    where it was shown as well as DAgger does. For calibrating a task on pair seeds
    (scripts/calibrate.sh), not for a benchmark's own numbers."""
    lanes: int = field(default=1, metadata=STAMPED_UNLESS_DEFAULT)
    """Episodes of a seed stepped in lockstep, one trunk forward per step for all of them, at this
    batch shape (:mod:`metadagger.imitation.lanes`); 1 rolls each episode out alone. The numbers
    depend on it (a batch of one rounds the last bits otherwise), never on the workers."""

    def check_serves(self, *, discrete: bool, task: str) -> None:
        """Raise a :class:`UserError` where ``dart`` runs on a task with classes at a noise that is no
        probability (its ``dart_noise`` above 1)."""
        if discrete and DART in self.methods and self.dart_noise > 1:
            raise UserError(
                f"benchmark.dart_noise is {self.dart_noise}, but {task} acts with classes, where it is the probability "
                "of another class: give one in [0, 1], e.g. 0.2"
            )

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("benchmark.seeds must not be empty")
        both = sorted(set(self.seeds) & set(self.confirm_seeds))
        if both:
            raise UserError(f"benchmark.confirm_seeds must be other seeds than benchmark.seeds, both hold {both[:5]}")
        if not self.methods:
            raise UserError(f"benchmark.methods must not be empty; allowed: {', '.join(benchmark_methods())}")
        check_methods(self.methods, "benchmark.methods")
        gated = gated_methods(references=True)
        for name, what in (("grids", self.grids), ("gate_options", self.gate_options)):
            bad = sorted(set(what) - set(gated))
            if bad:
                raise UserError(f"benchmark.{name} has unknown method(s) {bad}; allowed: {', '.join(gated)}")
        for method in self.gated():
            grid = self.grid(method)
            if not grid:
                raise UserError(
                    f"benchmark.grids.{method} is empty; give its settings, e.g. {list(get_gate(gated[method]).grid)}"
                )
            for value in grid:
                make_gate(gated[method], value, **self.options_of(method))  # range checks now, not hours later
        if (
            1.0 not in self.demo_fractions
            or any(not 0.0 < f <= 1.0 for f in self.demo_fractions)
            or len(set(self.demo_fractions)) != len(self.demo_fractions)
        ):
            raise UserError(
                f"benchmark.demo_fractions must be distinct shares in (0, 1] with 1 among them, got "
                f"{list(self.demo_fractions)}; e.g. [0.25, 0.5, 1.0]"
            )
        check_lanes("benchmark.lanes", self.lanes)
        if (
            isinstance(self.dart_noise, bool)
            or not isinstance(self.dart_noise, (int, float))
            or not (0.0 <= self.dart_noise < float("inf"))
        ):
            raise UserError(f"benchmark.dart_noise must be a number >= 0, got {self.dart_noise!r}; e.g. 0.2")
        every = self.held_out_every
        if isinstance(every, bool) or not isinstance(every, int) or every < 0 or every == 1:
            raise UserError(
                f"benchmark.held_out_every must be 0 (none) or an integer >= 2, got {self.held_out_every!r}; e.g. 5"
            )
        if DART in self.methods and "dagger" not in self.methods:
            raise UserError(
                "benchmark.methods has dart, whose budgets are plain DAgger's labels after each round; add dagger"
            )
        if self.ensemble_heads < 2 or self.novelty_k < 1:
            raise UserError(
                f"benchmark.ensemble_heads must be >= 2 and benchmark.novelty_k >= 1, got "
                f"{self.ensemble_heads} and {self.novelty_k}"
            )

    def gated(self) -> list[str]:
        """The gated methods this config runs, the oracle last where ``oracle`` is on."""
        gated = gated_methods(references=True)
        chosen = [m for m in self.methods if m in gated]
        return chosen + [m for m in reference_methods() if self.oracle and m not in chosen]

    def grid(self, method: str) -> list[float]:
        """A gated method's sweep: ``grids``' entry, else its gate's declared grid."""
        if method in self.grids:
            return list(self.grids[method])
        return list(gate_of_method(method).grid)

    def options_of(self, method: str) -> dict[str, Any]:
        """Keyword options of a gated method's gate: the shared options it declares, then ``gate_options``."""
        declaration = gate_of_method(method)
        shared = {name: getattr(self, option) for name, option in declaration.shared.items()}
        return {**shared, **self.gate_options.get(method, {})}
