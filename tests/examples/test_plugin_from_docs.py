"""The gate of docs/benchmark.md's "Adding a gate", installed as a package and run in a benchmark.

The test reads the two files the docs show, the package's ``__init__.py`` and its
``pyproject.toml``: it builds them into a wheel, and writes the module with the entry points the
``pyproject.toml`` declares (``plugins`` in conftest.py), then runs the gate beside DAgger and the
built-in uncertainty gates on the toy corridor, in a worker process that finds it on its own, and
runs the docs' view made by hand: what the docs show works as they show it.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import pytest
import torch
from plugin_kit import toy_benchmark

import metadagger.imitation.gate_registry as registry
from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig

DOCS = Path(__file__).resolve().parents[2] / "docs" / "benchmark.md"
MARK = "<!-- plug-in example: tests/examples/test_plugin_from_docs.py builds these two files as a package -->"
VIEW_MARK = "<!-- view example: tests/examples/test_plugin_from_docs.py runs this block with the gate installed -->"


def _block(mark: str, language: str) -> str:
    """The first ``language`` block that follows ``mark`` in the docs, dedented (a list item indents it)."""
    text = DOCS.read_text()
    assert mark in text, f"docs/benchmark.md lost its mark {mark!r}"
    return textwrap.dedent(re.search(rf"```{language}\n(.*?)```", text[text.index(mark) :], re.S).group(1))


def docs_plugin() -> str:
    """The Python block that follows the docs' plug-in mark: the package's ``__init__.py``."""
    return _block(MARK, "python")


def docs_pyproject() -> dict:
    """The TOML block that follows the docs' plug-in mark: the package's ``pyproject.toml``, parsed."""
    return tomllib.loads(_block(MARK, "toml"))


def _package(root: Path) -> Path:
    """The docs' two files laid out as the docs show them, under ``root/metadagger-unsure``."""
    package = root / "metadagger-unsure"
    (package / "src" / "metadagger_unsure").mkdir(parents=True)
    (package / "pyproject.toml").write_text(_block(MARK, "toml"))
    (package / "src" / "metadagger_unsure" / "__init__.py").write_text(docs_plugin())
    return package


@pytest.fixture
def unsure(plugins, tmp_path, monkeypatch):
    """The docs' gate installed as its ``pyproject.toml`` says (forgotten afterwards)."""
    monkeypatch.syspath_prepend(str(_package(tmp_path) / "src"))
    project = docs_pyproject()["project"]
    plugins(project["name"], project["entry-points"][registry.ENTRY_POINT_GROUP])
    yield
    sys.modules.pop("metadagger_unsure", None)


def test_the_docs_plug_in_is_short_and_uses_public_names_only():
    code = docs_plugin()
    assert len(code.strip().splitlines()) <= 30
    imported = [node.module for node in ast.walk(ast.parse(code)) if isinstance(node, ast.ImportFrom)]
    ours = [module for module in imported if module.startswith("metadagger")]
    assert ours and all(not part.startswith("_") for module in ours for part in module.split("."))
    assert "._" not in code and "def select(self, view: LearnerView)" in code  # the public hook, nothing private


def test_the_docs_pyproject_is_whole_and_builds_a_wheel_the_registry_reads(tmp_path):
    pyproject = docs_pyproject()
    assert pyproject["project"]["entry-points"] == {registry.ENTRY_POINT_GROUP: {"unsure": "metadagger_unsure:UNSURE"}}
    # the build backend the docs name makes the wheel offline, from the two files alone
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q"]
        + ["--wheel-dir", str(tmp_path / "wheels"), str(_package(tmp_path))],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, built.stderr
    [wheel] = (tmp_path / "wheels").glob("metadagger_unsure-0.1.0-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        assert "metadagger_unsure/__init__.py" in names
        [entry_points] = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
        assert archive.read(entry_points).decode().split() == [
            "[metadagger.gates]",
            "unsure",
            "=",
            "metadagger_unsure:UNSURE",
        ]


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


def test_the_docs_view_made_by_hand_runs_the_gate(unsure):
    scope: dict = {}
    exec(_block(VIEW_MARK, "python"), scope)
    view, chosen = scope["view"], scope["chosen"]
    assert len(view.features) == 50 and chosen.mask.dtype == torch.bool and chosen.mask.shape == (50,)
    confidence = view.probabilities().max(dim=1).values
    assert torch.equal(chosen.mask, confidence < 0.6)
