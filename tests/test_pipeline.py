"""Smoke tests of the real commands on CarRacing with the tiny ``ci`` preset."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from metadagger.cli import app
from metadagger.evaluation.rows import read_csv

runner = CliRunner()


def test_reproduce_ci_preset_writes_every_artifact_and_resumes(tmp_path):
    run = tmp_path / "run"
    result = runner.invoke(app, ["reproduce", "--task", "carracing", "--preset", "ci", "--out", str(run), "--workers", "2"])
    assert result.exit_code == 0, result.output
    assert (run / "config.yaml").is_file()
    assert (run / "groundtruth" / "policy.safetensors").is_file()
    summary = json.loads((run / "pairs" / "summary.json").read_text())
    assert summary["seeds"] == 4
    for kind in ("dm", "sam", "tam", "mean-da", "pistar-head"):
        assert (run / "mappers" / kind / "mapper.safetensors").is_file()
    rows = read_csv(run / "eval" / "mdm.csv")
    assert {r["method"] for r in rows} == {"bc", "dm", "sam", "tam", "mean-da", "pistar-head"}
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

    # the report is rebuilt from the CSV/JSON alone
    (run / "report" / "report.md").unlink()
    assert runner.invoke(app, ["report", "--out", str(run)]).exit_code == 0
    assert (run / "report" / "report.md").read_text() == report


def test_demo_ci_preset(tmp_path):
    result = runner.invoke(app, ["demo", "--task", "carracing", "--preset", "ci", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "| BC |" in result.output and "| DAgger |" in result.output
    for name in ("table.md", "metrics.json", "rounds.csv", "success_vs_round.png", "bc.safetensors", "dagger.safetensors"):
        assert (tmp_path / "demo" / name).is_file()
