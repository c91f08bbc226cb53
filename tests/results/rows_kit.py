"""Benchmark rows made by hand, and a registry run holding them, for the tests of the generated blocks."""

from __future__ import annotations

import json
from pathlib import Path

from metadagger.evaluation.benchmark.protocol import FIELDS
from metadagger.evaluation.benchmark.summary import summarize_benchmark
from metadagger.evaluation.rows import write_csv
from metadagger.results.registry import RegistryRun
from metadagger.results.tables import BlockContext
from metadagger.utils.kernels import NUMERICS

SEEDS = tuple(range(5000, 5020))


def rows(method: str, setting: str, solved: int, queries: int) -> list[dict]:
    """``method`` at ``setting`` on every seed of :data:`SEEDS`, succeeding on the first ``solved``."""
    return [
        {
            "method": method,
            "setting": setting,
            "demo_fraction": 1.0,
            "seed": seed,
            "success": i < solved,
            "reward": 900.0 if i < solved else 100.0,
            "steps": 100,
            "expert_queries": queries,
            "takeovers": 1,
            "episodes_asked": 1,
        }
        for i, seed in enumerate(SEEDS)
    ]


def _write(folder: Path, made: list[dict]) -> None:
    folder.mkdir(parents=True)
    write_csv(folder / "queries.csv", made, fields=FIELDS)
    (folder / "summary.json").write_text(json.dumps(summarize_benchmark(made, {"pistar": 1000, "pairs": 5000})))


def registry_context(
    tmp_path: Path, name: str, made: list[dict], *, confirm: list[dict] | None = None, stale: bool = False
) -> BlockContext:
    """A registry of one run ``name`` whose benchmark made ``made`` (and ``confirm`` on its confirmation
    seeds), for blocks in ``docs/findings.md``."""
    run = tmp_path / "results" / name
    _write(run / "benchmark", made)
    if confirm is not None:
        _write(run / "benchmark" / "confirm", confirm)
    found = RegistryRun(run, {"machine": {"cpu": "CPU", "numerics": NUMERICS}})
    context = BlockContext({name: found}, tmp_path, stale={name: ["x"]} if stale else {})
    return context.at(tmp_path / "docs" / "findings.md")
