"""Generated blocks from the speed records kept in ``results/bench/`` (``metadagger bench ... --out``),
so that a page states a measured time or ratio only as its record holds it."""

from __future__ import annotations

from typing import Any

from metadagger.evaluation.report.run import STAGE_ORDER, duration
from metadagger.evaluation.report.tables import markdown_table
from metadagger.results.registry import REGISTRY
from metadagger.results.tables import BlockContext
from metadagger.utils.io import read_json

#: Where the speed records are kept, under the repository root.
BENCH = f"{REGISTRY}/bench"


def arms_table(context: BlockContext, file: str) -> str:
    """A record of whole runs side by side (``bench reproduce``: ``arms``, each with its stages'
    seconds and its largest process's peak memory): a row per arm with each stage's time (a stage
    no arm ran is left out), their sum, the first arm's sum over this one's, and the peak; then what
    ran beside, as recorded."""
    path = context.root / BENCH / file
    if not path.is_file():
        raise ValueError(f"{BENCH}/{file} does not exist")
    record = read_json(path, f"the speed record {BENCH}/{file}")
    arms: Any = record.get("arms") if isinstance(record, dict) else None
    if (
        not isinstance(arms, dict)
        or not arms
        or not all(isinstance(a, dict) and isinstance(a.get("stages"), dict) for a in arms.values())
    ):
        raise ValueError(f"{BENCH}/{file} holds no arms with stage seconds")
    named = {stage for arm in arms.values() for stage, seconds in arm["stages"].items() if seconds > 0}
    stages = [s for s in STAGE_ORDER if s in named] + sorted(named - set(STAGE_ORDER))
    totals = {name: sum(arm["stages"].values()) for name, arm in arms.items()}
    first = next(iter(totals.values()))
    rows = [
        (
            f"`{name}`" + (f" ({arm['commit']})" if arm.get("commit") and arm["commit"] not in name else ""),
            *(duration(arm["stages"][s]) if s in arm["stages"] else "-" for s in stages),
            duration(totals[name]),
            f"{first / totals[name]:.2f}x",
            f"{arm['peak_memory_mb']:,.0f} MB" if "peak_memory_mb" in arm else "-",
        )
        for name, arm in arms.items()
    ]
    header = ("arm", *stages, "all stages", "speed-up", "peak memory")
    note = (
        f"*From [`{file}`]({context.link(path)}): each stage's wall time, the first arm's sum over each arm's "
        "(speed-up), the largest process's peak resident memory."
        + (f" Beside them: {record['beside']}.*" if record.get("beside") else "*")
    )
    return "\n".join(markdown_table(header, rows) + ["", note])
