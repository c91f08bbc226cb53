"""Smoke tests of the real commands on CarRacing and Fetch with the tiny ``ci`` preset."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.evaluation.benchmark.methods import MDI_METHODS
from metadagger.evaluation.report.mdi import FIGURE as MDI_FIGURE
from metadagger.evaluation.rows import read_csv
from metadagger.mapping.registry import kind_names
from metadagger.pipeline import stages
from metadagger.pipeline.run_config import load_run
from metadagger.pipeline.stages import init_run, reproduce, stage_mdi
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import LOCK_FILE

runner = CliRunner()


def test_a_ci_run_has_every_artifact_and_the_command_line_resumes_it(carracing_ci_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(carracing_ci_run, run)
    assert (run / "config.yaml").is_file()
    assert (run / "pistar" / "policy.safetensors").is_file()
    summary = json.loads((run / "pairs" / "summary.json").read_text())
    assert summary["seeds"] == 4
    for kind in ("dm", "sam", "tam", "ridge", "mean-da", "pistar-head"):
        assert (run / "mappers" / kind / "mapper.safetensors").is_file()
    rows = read_csv(run / "eval" / "mdm.csv")
    assert {r["method"] for r in rows} == {"bc", "dm", "sam", "tam", "ridge", "mean-da", "pistar-head"}
    assert {r["seed"] for r in rows} == {5000, 5001}
    for r in rows:
        assert (run / "eval" / "heads" / r["method"] / f"{r['seed']}.safetensors").is_file()
    report = (run / "report" / "report.md").read_text()
    assert "Table 1" in report and "Table 2" in report and "pi*-head (control)" in report
    assert (run / "report" / "figures" / "mdm_vs_bc.png").is_file()

    # a finished run resumes instantly: every stage finds its artifacts
    before = {p: p.stat().st_mtime_ns for p in run.rglob("*.safetensors")}
    again = runner.invoke(app, ["reproduce", "--task", "carracing", "--preset", "ci", "--out", str(run)])
    assert again.exit_code == 0, again.output
    assert {p: p.stat().st_mtime_ns for p in run.rglob("*.safetensors")} == before
    times = json.loads((run / "stage_times.json").read_text())
    assert set(times) == {"pistar", "pairs", "mappers", "evaluate", "mdi", "benchmark"}
    assert all(t["total_seconds"] >= t["seconds"] >= 0 for t in times.values())

    # the report is rebuilt from the CSV/JSON alone
    report = (run / "report" / "report.md").read_text()
    (run / "report" / "report.md").unlink()
    assert runner.invoke(app, ["report", "--out", str(run)]).exit_code == 0
    assert (run / "report" / "report.md").read_text() == report


def test_a_stopped_stage_call_still_counts_in_the_stage_times(tmp_path, monkeypatch):
    run = tmp_path / "run"
    init_run(run, "carracing", "ci")

    def stage_pistar(layout, config, options):  # stopped by SIGTERM or Ctrl-C mid-way
        raise KeyboardInterrupt

    monkeypatch.setattr(stages, "stage_pistar", stages.records_config(stage_pistar))
    with pytest.raises(KeyboardInterrupt):
        reproduce("carracing", "ci", run, options=StageOptions(progress=False))
    entry = json.loads((run / "stage_times.json").read_text())["pistar"]
    assert entry["stopped"] is True and entry["total_seconds"] == entry["seconds"] >= 0
    monkeypatch.undo()
    stages.stage_pistar(RunLayout(run), load_run(run), StageOptions(progress=False))
    again = json.loads((run / "stage_times.json").read_text())["pistar"]
    assert "stopped" not in again and again["total_seconds"] == pytest.approx(
        entry["total_seconds"] + again["seconds"], abs=2e-3
    )


def test_demo_ci_preset(tmp_path):
    result = runner.invoke(app, ["demo", "--task", "carracing", "--preset", "ci", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "| BC |" in result.output and "| DAgger |" in result.output
    for name in (
        "table.md",
        "metrics.json",
        "rounds.csv",
        "success_vs_round.png",
        "bc.safetensors",
        "dagger.safetensors",
    ):
        assert (tmp_path / "demo" / name).is_file()


def test_demo_clones_from_a_minari_dataset(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    import gymnasium as gym
    import numpy as np
    from minari.data_collector import EpisodeBuffer

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (8, 96, 96, 3), dtype=np.uint8)
    image = gym.spaces.Box(0, 255, (96, 96, 3), np.uint8)
    for name, classes in (("test/steer-v0", 20), ("test/three-v0", 3)):
        buffer = EpisodeBuffer(
            id=0,
            seed=0,
            observations=obs,
            actions=rng.integers(0, classes, 7),
            rewards=[0.0] * 7,
            terminations=[False] * 6 + [True],
            truncations=[False] * 7,
        )
        minari.create_dataset_from_buffers(
            name, [buffer], observation_space=image, action_space=gym.spaces.Discrete(classes)
        )
    result = runner.invoke(
        app, ["demo", "--task", "carracing", "--preset", "ci", "--out", str(tmp_path), "--demos", "test/steer-v0"]
    )
    assert result.exit_code == 0, result.output
    bc_row = next(line for line in result.output.splitlines() if line.startswith("| BC |"))
    assert bc_row.rstrip(" |").endswith("| 7")  # the dataset's 7 labelled states are BC's expert queries
    result = runner.invoke(
        app, ["demo", "--task", "carracing", "--preset", "ci", "--out", str(tmp_path), "--demos", "test/three-v0"]
    )
    assert (
        result.exit_code == 2 and "action space Discrete(3), but the task's learner has Discrete(20)" in result.output
    )


def _stamps(run: Path) -> dict[Path, int]:
    """Modification times of the files a stage writes only when it does work: checkpoints and resume
    logs (the benchmark's query ledger, ``labels.jsonl``, is a table, written with ``queries.csv``)."""
    return {
        p: p.stat().st_mtime_ns
        for pattern in ("*.safetensors", "*.jsonl")
        for p in run.rglob(pattern)
        if p.name != "labels.jsonl"
    }


@pytest.fixture(scope="module")
def fetch_ci_run(tmp_path_factory) -> Path:
    """A finished Fetch ci run on 2 workers, made once for this module; copy it before changing it."""
    pytest.importorskip("gymnasium_robotics")
    run = tmp_path_factory.mktemp("fetch-ci") / "run"
    reproduce("fetch", "ci", run, options=StageOptions(workers=2, progress=False))
    return run


def test_reproduce_fetch_ci_runs_mdi_and_resumes(fetch_ci_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(fetch_ci_run, run)
    report = (run / "report" / "report.md").read_text()
    # only the kinds the run uses: evaluate.methods [dm, ridge, mean-da, pistar-head] and mdi.mapper dm
    assert sorted(p.name for p in (run / "mappers").iterdir()) == ["dm", "mean-da", "pistar-head", "ridge"]
    rows = read_csv(run / "eval" / "mdi.csv")
    methods = MDI_METHODS + ("dagger-mdi-mean-da", "dagger-mdi-pistar-head")  # mdi.controls
    assert [(r["method"], r["seed"]) for r in rows] == [(m, s) for s in (5000, 5001) for m in methods]
    assert not (run / "eval" / "oneshot.csv").exists()  # evaluate.oneshot is false
    assert "Table 1" in report and "## One-shot" not in report
    assert "## MDI" in report and "Table 7" in report and "| DAgger-MDI |" in report
    assert "| control: DAgger-MDI initialised by mean-da |" in report
    assert (run / "report" / "figures" / MDI_FIGURE).is_file()

    # a finished run resumes without redoing any stage, from reproduce and from the CLI
    before = _stamps(run)
    assert _without_times(
        reproduce("fetch", "ci", run, options=StageOptions(progress=False)).read_text()
    ) == _without_times(report)
    again = runner.invoke(app, ["evaluate", "--out", str(run)])
    assert again.exit_code == 0, again.output
    assert (
        "MDM: evaluated 2 seeds" in again.output
        and f"MDI: evaluated 2 seeds; wrote {run / 'eval' / 'mdi.csv'}" in again.output
    )
    assert _stamps(run) == before


def _without_times(report: str) -> str:
    """A report without its "Run" section, the stages' wall times."""
    head, _, rest = report.partition("\n## Run\n")
    return head + ("\n## " + rest.partition("\n## ")[2] if rest else "")


def _artifacts(run: Path) -> dict[str, bytes | list[bytes]]:
    """Every artifact but the report (whose title names the run folder), the lock file (which
    names the process that wrote) and the stages' wall times, by relative path. The JSON-lines
    resume logs list seeds in the order workers finished them, so their lines are compared as a
    sorted list."""
    return {
        str(p.relative_to(run)): sorted(p.read_bytes().splitlines()) if p.suffix == ".jsonl" else p.read_bytes()
        for p in sorted(run.rglob("*"))
        if p.is_file() and "report" not in p.parts and p.name not in (LOCK_FILE, "stage_times.json")
    }


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_fetch_pipeline_is_deterministic_across_runs_and_worker_counts(fetch_ci_run, tmp_path):
    first = _artifacts(fetch_ci_run)
    second = _artifacts(
        reproduce("fetch", "ci", tmp_path / "b", options=StageOptions(workers=1, progress=False)).parent.parent
    )
    assert any(name.startswith("pairs/") and name.endswith(".safetensors") for name in first)
    assert first.keys() == second.keys()
    assert [name for name in first if first[name] != second[name]] == []


def test_mapper_kinds_follow_the_run_config(tmp_path):
    # every kind but the opt-in modes and conditioned (docs/mapping.md), in registry order
    assert init_run(tmp_path / "cr", "carracing", "ci").mapper_kinds == tuple(
        k for k in kind_names() if k not in ("modes", "conditioned")
    )
    assert init_run(tmp_path / "crm", "carracing", "ci", overrides=["evaluate.methods=[modes, dm]"]).mapper_kinds == (
        "dm",
        "modes",
    )
    assert init_run(tmp_path / "fetch", "fetch", "ci").mapper_kinds == ("dm", "ridge", "mean-da", "pistar-head")


def test_stage_mdi_skips_runs_without_mdi_and_checks_seeds(tmp_path):
    assert stage_mdi(RunLayout(tmp_path / "cr"), init_run(tmp_path / "cr", "carracing", "ci")) == []
    with pytest.raises(UserError, match="evaluation seeds must be unseen, but \\[1000\\]"):
        stage_mdi(RunLayout(tmp_path / "fetch"), init_run(tmp_path / "fetch", "fetch", "ci"), seeds=[1000, 5000])


@pytest.mark.slow  # about a minute on two cores: the suite's ten minutes have no room left for it
def test_the_labels_matter_task_runs_every_stage_with_its_controls_on_the_ci_preset(tmp_path):
    """carracing-echo's smoke test: its presets' variant (faults, no band) through every stage, with
    BC refitted, DART, DAgger-MDI, the priors and the disagreement gate in the benchmark."""
    run = tmp_path / "echo"
    result = runner.invoke(app, ["reproduce", "--task", "carracing-echo", "--preset", "ci", "--out", str(run)])
    assert result.exit_code == 0, result.output
    config = load_run(run)
    assert config.task_options["fault_rate"] > 0 and config.task_options["echo_rows"] == 0
    methods = {row["method"] for row in read_csv(run / "benchmark" / "queries.csv")}
    assert {"bc-refit", "dart", "dagger", "dagger-oracle", "disagree-dm", "disagree-mean-da"} <= methods
    assert {"dagger-mdi", "dagger-xavier", "prior-dm", "prior-zero", "prior-dagger-mean-da"} <= methods
    assert {row["method"] for row in read_csv(run / "eval" / "mdi.csv")} >= {"dagger-mdi", "dagger-mdi-mean-da"}
    assert (run / "report" / "report.md").is_file()
