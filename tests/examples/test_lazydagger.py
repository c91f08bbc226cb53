"""The worked example examples/lazydagger: a gate in a package of its own, found through its entry point.

The example is installed with ``pip install -e examples/lazydagger``; the tests do not install it.
They write what installing it writes for its entry point, read from its ``pyproject.toml``
(``plugins`` in conftest.py), and put the example's source folder on ``sys.path``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import torch
from plugin_kit import toy_benchmark
from typer.testing import CliRunner

import metadagger.imitation.gate_registry as registry
from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.ledger import step_runs
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.gate_view import Labelled, LearnerView
from metadagger.imitation.gates import SafeGate

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lazydagger"
PYPROJECT = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())
runner = CliRunner()


@pytest.fixture(autouse=True)
def example_source(monkeypatch):
    """The example's source folder on the path, as an editable install puts it (forgotten afterwards)."""
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    yield
    _forget_example()


def _forget_example() -> None:
    for module in [m for m in sys.modules if m.split(".")[0] == "metadagger_lazydagger"]:
        del sys.modules[module]


@pytest.fixture
def lazy(plugins):
    """The example installed as its ``pyproject.toml`` says; returns the folder holding its metadata."""
    return plugins(PYPROJECT["project"]["name"], PYPROJECT["project"]["entry-points"][registry.ENTRY_POINT_GROUP])


@pytest.fixture
def gate_module():
    """The example's package, imported from its source folder."""
    import metadagger_lazydagger

    return metadagger_lazydagger


# --- the gate on hand-made scores and features ---------------------------------------------------


def test_hysteresis_holds_the_expert_from_a_takeover_to_a_hand_back(gate_module):
    scores = torch.tensor([0.0, 1, 5, 3, 6, 2, 0.5, 0, 7, 1])
    driven = gate_module.hysteresis(scores, high=4, low=1)
    assert driven.tolist() == [False, False, True, True, True, True, False, False, True, True]
    plain = scores > 4  # the same threshold without hysteresis: three takeovers, not two
    assert step_runs(plain.nonzero().squeeze(1).numpy()) == [[2, 3], [4, 5], [8, 9]]
    assert step_runs(driven.nonzero().squeeze(1).numpy()) == [[2, 6], [8, 10]]
    assert gate_module.hysteresis(scores, high=4, low=4).tolist() == plain.tolist()  # no score equals 4
    assert gate_module.hysteresis(scores, high=4, low=0).tolist() == [False, False] + [True] * 8
    with pytest.raises(UserError, match="must not be above the takeover threshold"):
        gate_module.hysteresis(scores, high=1, low=4)


def _round(n: int = 160) -> tuple[torch.Tensor, torch.Tensor, Labelled]:
    """One feature x per state: the labelled states' learner is wrong exactly where x > 0.5, so the
    safe gate's score rises with x; this round's x is a noisy wave (one episode, in step order)."""
    grid = torch.linspace(0.0, 1.0, 41).unsqueeze(1)
    labelled = Labelled(
        features=grid, labels=torch.zeros(41, dtype=torch.int64), learner_actions=(grid[:, 0] > 0.5).long()
    )
    noise = torch.randn(n, generator=torch.Generator().manual_seed(0))
    x = 0.5 + 0.4 * torch.sin(torch.arange(n) / 9.0) + 0.12 * noise
    return x.unsqueeze(1).float(), torch.zeros(n, dtype=torch.int64), labelled


def _view(features: torch.Tensor, actions: torch.Tensor, labelled: Labelled) -> LearnerView:
    """The round as a learner of two classes with an all-zero head saw it, taking ``actions``."""
    return LearnerView.of(features, torch.zeros(2 * (features.shape[1] + 1)), labelled, actions=actions)


@pytest.mark.parametrize("quantile", [0.5, 0.8, 0.95])
def test_fewer_longer_runs_than_the_safe_gate_at_the_same_quantile(gate_module, quantile):
    features, actions, labelled = _round()
    gate = gate_module.LazyGate(quantile)
    chosen = gate.choose(_view(features, actions, labelled))
    safe = SafeGate(quantile).choose(_view(features, actions, labelled))
    assert torch.equal(chosen.scores, safe.scores)  # SafeDAgger's score, unchanged
    assert chosen.scores[1:].gt(chosen.scores[:-1]).eq(features[1:, 0] > features[:-1, 0]).all()  # rises with x

    lazy_runs = step_runs(chosen.mask.nonzero().squeeze(1).numpy())
    safe_runs = step_runs(safe.mask.nonzero().squeeze(1).numpy())
    assert (chosen.mask | safe.mask).equal(chosen.mask)  # every step the safe gate labels is labelled
    assert len(lazy_runs) < len(safe_runs)  # fewer takeovers
    assert chosen.mask.sum() / len(lazy_runs) > safe.mask.sum() / len(safe_runs)  # longer ones

    scores = chosen.scores.double()
    high = torch.quantile(scores, quantile)
    low = torch.quantile(scores, gate.hand_back)
    assert gate.hand_back == quantile / 2
    for start, stop in lazy_runs:
        assert scores[start] > high  # a takeover
        assert (scores[start:stop] >= low).all()  # every step until the hand-back is the expert's
        assert stop == len(scores) or scores[stop] < low  # the hand-back
    learner = ~chosen.mask
    after_learner = torch.cat([torch.tensor([True]), learner[:-1]])  # the learner drove the step before
    assert not (learner & after_learner & (scores > high)).any()  # no step above high left to the learner


def test_a_lower_hand_back_labels_more_in_fewer_runs(gate_module):
    features, actions, labelled = _round()
    masks = [
        gate_module.LazyGate(0.8, low=low).choose(_view(features, actions, labelled)).mask
        for low in (0.8, 0.6, 0.3, 0.0)
    ]
    counts = [int(m.sum()) for m in masks]
    runs = [len(step_runs(m.nonzero().squeeze(1).numpy())) for m in masks]
    assert counts == sorted(counts) and runs == sorted(runs, reverse=True) and runs[-1] == 1


def test_round_one_labels_every_state_as_the_safe_gate(gate_module):
    features, actions, _ = _round()
    demonstration = Labelled(features=features[:20], labels=actions[:20], learner_actions=actions[:20])
    chosen = gate_module.LazyGate(0.8).choose(_view(features, actions, demonstration))
    assert chosen.mask.all() and chosen.scores is None


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"quantile": 1.0}, "LazyGate.quantile must be a number in [0, 1), got 1.0"),
        ({"quantile": -0.1}, "LazyGate.quantile must be a number in [0, 1), got -0.1"),
        ({"quantile": float("nan")}, "LazyGate.quantile must be a number in [0, 1), got nan"),
        ({"quantile": "0.5"}, "LazyGate.quantile must be a number in [0, 1), got '0.5'"),
        ({"quantile": 0.5, "low": 0.6}, "LazyGate.low must be a number in [0, quantile] = [0, 0.5], got 0.6"),
        ({"quantile": 0.5, "low": -0.01}, "LazyGate.low must be a number in [0, quantile] = [0, 0.5], got -0.01"),
        ({"quantile": 0.5, "ridge": 0.0}, "LazyGate.ridge must be a number > 0, got 0.0"),
    ],
)
def test_bad_settings_are_user_errors(gate_module, fields, message):
    with pytest.raises(UserError) as error:
        gate_module.LazyGate(**fields)
    assert str(error.value) == message


# --- the entry point ------------------------------------------------------------------------------


def test_the_entry_point_makes_dagger_lazy_a_benchmark_method(lazy):
    from metadagger_lazydagger import LAZY, LazyGate

    assert PYPROJECT["project"]["entry-points"][registry.ENTRY_POINT_GROUP] == {"lazy": "metadagger_lazydagger:LAZY"}
    assert "metadagger" in PYPROJECT["project"]["dependencies"]
    assert "lazy" not in registry._GATES  # loaded on first use, not before
    assert registry.gate_declarations()["lazy"] is LAZY and LAZY.method == "dagger-lazy"

    config = BenchmarkConfig(methods=("bc", "dagger", "dagger-lazy"))
    assert config.gated() == ["dagger-lazy", "dagger-oracle"] and config.grid("dagger-lazy") == [0.5, 0.8, 0.95]
    gate = registry.make_gate(
        "lazy", 0.8, **BenchmarkConfig(gate_options={"dagger-lazy": {"low": 0.25}}).options_of("dagger-lazy")
    )
    assert gate == LazyGate(0.8, low=0.25)
    assert method_label("dagger-lazy") == "DAgger, LazyDAgger gate"

    with pytest.raises(UserError, match=r"LazyGate.low must be a number in \[0, quantile\] = \[0, 0.5\], got 0.6"):
        BenchmarkConfig(methods=("dagger-lazy",), gate_options={"dagger-lazy": {"low": 0.6}})  # the grid's 0.5
    with pytest.raises(UserError, match="unknown option.*lo for gate 'lazy': expected low, ridge"):
        BenchmarkConfig(methods=("dagger-lazy",), gate_options={"dagger-lazy": {"lo": 0.1}})

    listed = runner.invoke(app, ["config", "methods"])
    assert listed.exit_code == 0, listed.output
    assert "  dagger-lazy: LazyDAgger:" in listed.output
    assert "  lazy: DAgger, LazyDAgger gate; quantile in [0.5, 0.8, 0.95]; LazyDAgger:" in listed.output
    show = ["config", "show", "--task", "carracing", "--preset", "quick"]
    shown = runner.invoke(app, [*show, "--set", "benchmark.methods=[bc, dagger, dagger-lazy]"])
    assert shown.exit_code == 0, shown.output
    assert "dagger-lazy" in shown.output


def _command_line(site: Path, *args: str) -> subprocess.CompletedProcess:
    """``metadagger ARGS`` in a fresh process that sees the distributions installed under ``site``
    and the example's source, as a user's shell after ``pip install``."""
    path = os.pathsep.join([str(site), str(EXAMPLE / "src"), os.environ.get("PYTHONPATH", "")])
    return subprocess.run(
        [sys.executable, "-m", "metadagger.cli", *args],
        env={**os.environ, "PYTHONPATH": path, "COLUMNS": "400"},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_benchmark_help_lists_the_installed_gate(lazy):
    # the help's method list is made when the command line loads: a fresh process, as a user runs it
    result = _command_line(lazy, "benchmark", "--help")
    assert result.returncode == 0, result.stderr
    assert "dagger-lazy" in result.stdout


@pytest.mark.parametrize(
    "value, says",
    [
        ("metadagger_lazydagger_nope:LAZY", "fails to load (ModuleNotFoundError: No module named"),
        ("metadagger_lazydagger:LazyGate", "names a ABCMeta, not a GateDeclaration"),
        ("metadagger_lazydagger.gate:hysteresis", "names a function, not a GateDeclaration"),
    ],
)
def test_a_broken_plugin_is_one_line_naming_its_package(plugins, value, says):
    plugins("metadagger-brokengate", {"lazy": value})
    with pytest.raises(UserError) as error:
        registry.gate_declarations()
    message = str(error.value)
    assert "\n" not in message and says in message
    assert message.startswith(f"gate plug-in 'lazy' of package metadagger-brokengate ({value})")
    assert message.endswith("fix or uninstall metadagger-brokengate")


def test_the_command_line_names_a_broken_plugin(plugins):
    site = plugins("metadagger-brokengate", {"lazy": "metadagger_lazydagger_nope:LAZY"})
    result = _command_line(site, "config", "methods")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stdout + result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "metadagger-brokengate" in errors[0], result.stderr


# --- the benchmark on the toy corridor, end to end -------------------------------------------------


def test_the_benchmark_runs_the_installed_gate_end_to_end(lazy, toy_run):
    config = BenchmarkConfig(
        seeds=(300, 301),
        methods=("bc", "dagger", "dagger-lazy"),
        grids={"dagger-lazy": [0.5, 0.8]},
        gate_options={"dagger-lazy": {"low": 0.2}},
        oracle=False,
    )
    rows = toy_benchmark(toy_run, config)  # in a worker process: it finds the gate on its own
    lazy_rows = [r for r in rows if r["method"] == "dagger-lazy"]
    assert sorted((r["setting"], r["seed"]) for r in lazy_rows) == [
        ("0.5", 300),
        ("0.5", 301),
        ("0.8", 300),
        ("0.8", 301),
    ]
    assert {r["method"] for r in rows} == {"bc", "dagger", "dagger-lazy"}
    bc = {r["seed"]: r["expert_queries"] for r in rows if r["method"] == "bc"}
    for row in lazy_rows:
        assert 1 <= row["takeovers"] <= row["expert_queries"]
        assert row["expert_queries"] > bc[row["seed"]]  # round 1 labels the whole first rollout
        assert row["episodes_asked"] >= 2
    written = [r for r in read_csv(toy_run.benchmark_table) if r["method"] == "dagger-lazy"]
    assert len(written) == 4
    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert {e["setting"] for e in summary["entries"] if e["method"] == "dagger-lazy"} == {"0.5", "0.8"}
