"""Calibration records: a variant read on pair seeds, kept as a row of its task's calibration table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from metadagger.errors import UserError
from metadagger.pipeline.run_config import init_run
from metadagger.results.blocks import build
from metadagger.results.calibration import add_calibration, calibration_record

CALIBRATE = [
    "pairs.seeds=1500-1501",
    "benchmark.seeds=1000-1003",
    "benchmark.methods=[bc, bc-refit, dagger, dart]",
    "benchmark.held_out_every=5",
]


def _entry(method: str, setting: str, successes: int, queries: float, loss: float | None = None) -> dict:
    return {
        "method": method,
        "setting": setting,
        "demo_fraction": 1.0,
        "successes": successes,
        "seeds": 4,
        "mean_queries": queries,
        "mean_expert_loss": loss,
    }


def _comparison(method: str, setting: str, against: str, difference: float) -> dict:
    return {
        "method": method,
        "setting": setting,
        "against": against,
        "against_setting": "2",
        "difference": difference,
        "ci_low": difference - 0.25,
        "ci_high": min(difference + 0.25, 1.0),
        "seeds": 4,
    }


def _calibration_run(root: Path, *sets: str) -> Path:
    run = root / "run"
    init_run(run, "carracing-echo", "quick", overrides=[*CALIBRATE, *sets])
    entries = [
        _entry("bc", "", 1, 600.0, 0.3),
        _entry("bc-refit", "2", 1, 600.0),
        _entry("dagger", "1", 2, 1500.0, 0.5),
        _entry("dagger", "2", 4, 3000.0, 0.4),
        _entry("dart", "1", 1, 1500.0),
        _entry("dart", "2", 2, 3000.0),
    ]
    comparisons = [
        _comparison("dagger", "1", "bc-refit", 0.25),
        _comparison("dagger", "2", "bc-refit", 0.75),
        _comparison("dagger", "2", "dart", 0.5),
    ]
    (run / "benchmark").mkdir()
    (run / "pistar").mkdir()
    (run / "benchmark" / "summary.json").write_text(json.dumps({"entries": entries, "comparisons": comparisons}))
    (run / "pistar" / "metrics.json").write_text(json.dumps({"unseen_seeds": {"successes": 9, "episodes": 10}}))
    (run / "stage_times.json").write_text(json.dumps({"benchmark": {"commits": ["abc"]}}))
    losses = {("bc", ""): 0.5, ("bc-refit", "2"): 0.45, ("dagger", "1"): 0.6, ("dagger", "2"): 0.4}
    with open(run / "benchmark" / "rows.jsonl", "w") as log:  # the benchmark's per-seed rows
        for seed in range(1000, 1004):
            rows = {m: [] for m, _ in losses}
            for (method, setting), loss in losses.items():
                rows[method].append(
                    {"method": method, "setting": setting, "seed": seed, "expert_loss": loss + seed % 2 / 10}
                )
            entries = {m: {"stamp": {"method": m}, "rows": made} for m, made in rows.items()}
            log.write(json.dumps({"seed": seed, "entries": entries}) + "\n")
    return run


def test_a_record_names_what_sets_the_variant_apart_and_reads_each_method_after_its_last_round(tmp_path):
    run = _calibration_run(tmp_path, "task_options={echo_rows: 3, fault_rate: 0.02}", "pairs.bc.lr=5.0e-4")
    record = calibration_record(run)
    assert record["settings"] == {  # the preset's faults settings the run leaves out are None
        "pairs.bc.lr": 0.0005,
        "task_options.echo_rows": 3,
        "task_options.fault_rate": 0.02,
        "task_options.fault_offset": None,
        "task_options.fault_steps": None,
    }
    assert record["methods"]["dagger"] == {"successes": 4, "seeds": 4, "mean_queries": 3000.0, "mean_expert_loss": 0.4}
    assert record["methods"]["bc"]["mean_expert_loss"] == 0.3
    assert record["dagger_vs_refit"]["difference"] == 0.75  # the last round's, not the first's
    assert record["dagger_vs_dart"]["ci_low"] == 0.25
    assert record["pistar_unseen"] == {"successes": 9, "episodes": 10}
    # held-out losses paired with DAgger's after its last round (0.4, not the first round's 0.6)
    assert record["loss_vs_dagger"]["bc"]["difference"] == pytest.approx(0.1)
    assert record["loss_vs_dagger"]["bc-refit"]["ci_low"] == pytest.approx(0.05)
    (run / "benchmark" / "rows.jsonl").write_text("")
    assert calibration_record(run)["loss_vs_dagger"] == {}


def test_the_block_is_a_row_per_record_and_a_benchmark_without_dart_is_one_line(tmp_path):
    run = _calibration_run(
        tmp_path, "task_options={echo_rows: 3, fault_rate: 0.01, fault_steps: 10, fault_offset: 0.15}"
    )
    add_calibration(run, "band-3", tmp_path / "results")
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text("<!-- results: calibration carracing-echo -->\n<!-- /results -->\n")
    build(root=tmp_path, registry=tmp_path / "results")
    text = page.read_text()
    assert "| band-3 | `task_options.echo_rows` 3 | 9/10 | 1/4 | 1/4 | 2/4 | 4/4 | +75 (+50 to +100) |" in text
    assert "0.30 / - / - / 0.40 | +0.10 (+0.10 to +0.10); +0.05 (+0.05 to +0.05) | 3,000 |" in text
    summary = run / "benchmark" / "summary.json"
    data = json.loads(summary.read_text())
    summary.write_text(json.dumps({**data, "entries": [e for e in data["entries"] if e["method"] != "dart"]}))
    with pytest.raises(UserError, match="the benchmark has no 'dart' rows; calibrate with scripts/calibrate.sh"):
        calibration_record(run)
    with pytest.raises(UserError, match="--name must be"):
        add_calibration(run, "a b", tmp_path / "results")
