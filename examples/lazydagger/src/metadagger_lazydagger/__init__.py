"""LazyDAgger's switching with hysteresis as a metadagger gate (an example of a gate in a package of its own).

Installed, the entry point ``lazy`` in the group ``metadagger.gates`` names :data:`LAZY`, and the
benchmark runs the gate as the method ``dagger-lazy``.
"""

from metadagger.imitation.gate_registry import GateDeclaration
from metadagger_lazydagger.gate import LazyGate, hysteresis

#: The gate as the benchmark knows it; the entry point ``lazy`` names it.
LAZY = GateDeclaration(
    "lazy",
    LazyGate,
    "DAgger, LazyDAgger gate",
    (0.5, 0.8, 0.95),
    "LazyDAgger: the expert takes over above a quantile of SafeDAgger's mismatch score and keeps control until "
    "below a lower one",
)

__all__ = ["LAZY", "LazyGate", "hysteresis"]
