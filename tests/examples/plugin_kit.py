"""What the gate plug-in tests share: a distribution's entry points written where ``pip install``
would, and a benchmark on the toy corridor run in a worker process."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from toy_task import CorridorTask

import metadagger.imitation.gate_registry as registry
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.protocol import run_benchmark
from metadagger.imitation.bc import BCConfig
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout


def install_metadata(site: Path, name: str, entry_points: dict[str, str]) -> None:
    """What installing distribution ``name`` writes for its gate entry points: ``<name>-0.1.0.dist-info``."""
    info = site / f"{name.replace('-', '_')}-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1.0\n")
    lines = [f"{ep} = {value}" for ep, value in entry_points.items()]
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\n" + "\n".join(lines) + "\n")


def toy_benchmark(layout: RunLayout, config: BenchmarkConfig) -> list[dict[str, Any]]:
    """``config``'s benchmark on the toy corridor run ``layout``: two DAgger rounds, one-epoch head fits,
    in one worker process (which finds an installed gate through its entry point, as a user's would)."""
    fit = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
    return run_benchmark(
        CorridorTask(),
        layout,
        config,
        rounds=2,
        bc=fit,
        dagger_bc=fit,
        early_stop=None,
        kinds=("pistar-head",),
        mdi=None,
        meta_queries={"pistar": 900, "pairs": 100},
        options=StageOptions(workers=1, progress=False),
    )
