"""The gate of docs/benchmark.md's "Adding a gate", installed as a package and run in a benchmark.

The test reads the Python block the docs show, writes it as the package ``metadagger_unsure``
with its entry point (``plugins`` in conftest.py), and runs it beside DAgger and the built-in
uncertainty gates on the toy corridor, in a worker process that finds it on its own: what the docs
show works as they show it.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest
from plugin_kit import toy_benchmark

import metadagger.imitation.gate_registry as registry
from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig

DOCS = Path(__file__).resolve().parents[2] / "docs" / "benchmark.md"
MARK = "<!-- plug-in example: tests/examples/test_plugin_from_docs.py installs this block as a package -->"


def docs_plugin() -> str:
    """The Python block that follows the docs' plug-in mark."""
    text = DOCS.read_text()
    assert MARK in text, f"docs/benchmark.md lost its plug-in example's mark {MARK!r}"
    return re.search(r"```python\n(.*?)```", text[text.index(MARK) :], re.S).group(1)


@pytest.fixture
def unsure(plugins, tmp_path, monkeypatch):
    """The docs' gate installed as the package metadagger-unsure (forgotten afterwards)."""
    source = tmp_path / "src"
    (source / "metadagger_unsure").mkdir(parents=True)
    (source / "metadagger_unsure" / "__init__.py").write_text(docs_plugin())
    monkeypatch.syspath_prepend(str(source))
    plugins("metadagger-unsure", {"unsure": "metadagger_unsure:UNSURE"})
    yield
    sys.modules.pop("metadagger_unsure", None)


def test_the_docs_plug_in_is_short_and_uses_public_names_only():
    code = docs_plugin()
    assert len(code.strip().splitlines()) <= 30
    imported = [node.module for node in ast.walk(ast.parse(code)) if isinstance(node, ast.ImportFrom)]
    ours = [module for module in imported if module.startswith("metadagger")]
    assert ours and all(not part.startswith("_") for module in ours for part in module.split("."))
    assert "._" not in code.replace("._select", "")  # overriding _select is the interface; nothing else private


def test_the_docs_plug_in_runs_in_a_benchmark_beside_the_built_in_gates(unsure, toy_run):
    assert registry.gate_declarations()["unsure"].method == "dagger-unsure"
    config = BenchmarkConfig(
        seeds=(300, 301),
        methods=("bc", "dagger", "dagger-unsure", "dagger-least-confidence"),
        grids={"dagger-unsure": [0.9], "dagger-least-confidence": [0.5]},
        oracle=False,
    )
    rows = toy_benchmark(toy_run, config)  # in a worker process: it finds the gate on its own
    by_method = {m: [r for r in rows if r["method"] == m] for m in config.methods}
    assert [(r["setting"], r["seed"]) for r in by_method["dagger-unsure"]] == [("0.9", 300), ("0.9", 301)]
    bc = {r["seed"]: r["expert_queries"] for r in by_method["bc"]}
    dagger = {r["seed"]: r["expert_queries"] for r in by_method["dagger"] if r["setting"] == "2"}
    for row in by_method["dagger-unsure"] + by_method["dagger-least-confidence"]:
        assert bc[row["seed"]] < row["expert_queries"] <= dagger[row["seed"]]


def test_the_docs_plug_in_is_refused_on_action_vectors_before_any_work(unsure, tmp_path):
    from metadagger.pipeline.run_config import RunConfig
    from metadagger.pipeline.stage_inputs import run_task

    config = RunConfig(task="fetch", benchmark=BenchmarkConfig(methods=("bc", "dagger-unsure")))
    with pytest.raises(UserError) as refused:
        run_task(config)
    assert "dagger-unsure read the learner's class distribution, but task fetch acts with action vectors" in str(
        refused.value
    )
