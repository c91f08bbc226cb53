"""Blocks written from the speed records in results/bench/: a page's times and ratios are the
record's, and a missing or wrong record is one error line."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.results.blocks import build

runner = CliRunner()

RECORD = {
    "arms": {
        "before": {
            "commit": "abc1234",
            "stages": {"pairs": 300.0, "pistar": 200.0, "mdi": 0.0},
            "peak_memory_mb": 2048.4,
        },
        "after abc1234": {
            "commit": "abc1234",
            "stages": {"pistar": 100.0, "pairs": 150.0, "diagnose": 50.0},
            "peak_memory_mb": 1024.0,
        },
    },
    "beside": "nothing",
}


def _page(root: Path, spec: str) -> Path:
    (root / "docs").mkdir(exist_ok=True)
    page = root / "docs" / "page.md"
    page.write_text(f"# Speed\n\n<!-- results: {spec} -->\n<!-- /results -->\n")
    return page


def test_an_arms_block_has_each_stage_run_in_run_order_the_sum_the_speed_up_and_the_peak(tmp_path):
    (tmp_path / "results" / "bench").mkdir(parents=True)
    (tmp_path / "results" / "bench" / "whole.json").write_text(json.dumps(RECORD))
    page = _page(tmp_path, "bench-arms whole.json")
    assert len(build(tmp_path, registry=tmp_path / "results")) == 1
    lines = page.read_text().splitlines()
    assert "| arm | pistar | pairs | diagnose | all stages | speed-up | peak memory |" in lines
    assert "| `before` (abc1234) | 3 min 20 s | 5 min 00 s | - | 8 min 20 s | 1.00x | 2,048 MB |" in lines
    assert "| `after abc1234` | 1 min 40 s | 2 min 30 s | 50.0 s | 5 min 00 s | 1.67x | 1,024 MB |" in lines
    assert any("[`whole.json`](../results/bench/whole.json)" in line for line in lines)
    assert any("Beside them: nothing." in line for line in lines)
    assert build(tmp_path, registry=tmp_path / "results", check=True) == []

    # the record changes: check names the block
    changed = {
        **RECORD,
        "arms": {**RECORD["arms"], "after abc1234": {**RECORD["arms"]["after abc1234"], "peak_memory_mb": 900.0}},
    }
    (tmp_path / "results" / "bench" / "whole.json").write_text(json.dumps(changed))
    assert build(tmp_path, registry=tmp_path / "results", check=True) == [f"{page}:3 bench-arms whole.json"]


def _error_line(root: Path, spec: str) -> str:
    """What ``results build`` says of a page holding block ``spec``: one error line, exit code 2."""
    _page(root, spec)
    result = runner.invoke(app, ["results", "build", "--root", str(root), "--results", str(root / "results")])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_a_missing_record_or_one_without_arms_is_one_error_line(tmp_path):
    (tmp_path / "results" / "bench").mkdir(parents=True)
    (tmp_path / "results" / "bench" / "step.json").write_text(json.dumps({"per_env_step_ms": {}}))
    (tmp_path / "results" / "bench" / "list.json").write_text(json.dumps([{"arms": {}}]))
    (tmp_path / "results" / "bench" / "flat.json").write_text(json.dumps({"arms": {"a": 1.0}}))
    for spec, needle in (
        ("bench-arms gone.json", "results/bench/gone.json does not exist"),
        ("bench-arms step.json", "holds no arms"),
        ("bench-arms list.json", "holds no arms"),
        ("bench-arms flat.json", "holds no arms"),
    ):
        line = _error_line(tmp_path, spec)
        assert needle in line and "fix its arguments" in line, line


NUMERICS = {
    "task": "fetch",
    "width": 20,
    "states": 100000,
    "actions_changed": 99979,
    "share_changed": 0.99979,
    "median_output_difference": 1.4e-07,
    "p99_output_difference": 1.1e-06,
    "largest_output_difference": 7.9e-06,
}


def _outside(table: str, method: str, old: list[int], new: list[int], **group: str) -> dict:
    """A compared rate that left the old interval, as ``results compare`` records it."""
    return {"table": table, "column": "success", "method": method, "setting": "", **group, "old": old, "new": new}


COMPARISON = {
    "new": "results/fetch-quick",
    "old": "at-abc1234/results/fetch-quick",
    "rows": [{"table": "eval/mdm.csv"}] * 3,
    "outside": [
        _outside("eval/mdm.csv", "ridge", [1, 20], [10, 20]),
        _outside("benchmark/queries.csv", "dagger", [3, 10], [1, 10], setting="1", demo_fraction="1.0"),
    ],
    "only_new": ["benchmark/queries.csv success dagger-oracle/0.5/1.0"],
}


def test_a_numerics_block_has_a_row_per_record_with_its_counts_and_sizes(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "fetch.json").write_text(json.dumps(NUMERICS))
    older = {k: v for k, v in NUMERICS.items() if k not in ("median_output_difference", "p99_output_difference")}
    (bench / "old.json").write_text(
        json.dumps({**older, "task": "carracing", "actions_changed": 0, "share_changed": 0})
    )
    page = _page(tmp_path, "bench-numerics fetch.json old.json")
    assert len(build(tmp_path, registry=tmp_path / "results")) == 1
    lines = page.read_text().splitlines()
    assert "| record | task | lanes | states | actions changed | median | 99th percentile | largest |" in lines
    assert (
        "| [`fetch.json`](../results/bench/fetch.json) | `fetch` | 20 | 100,000 | 99,979 (99.98%) | 1.4e-07 | 1.1e-06 "
        "| 7.9e-06 |" in lines
    )
    assert (
        "| [`old.json`](../results/bench/old.json) | `carracing` | 20 | 100,000 | 0 (0.00%) | - | - | 7.9e-06 |"
        in lines
    )
    assert build(tmp_path, registry=tmp_path / "results", check=True) == []


def test_a_compare_block_counts_each_comparison_and_names_each_rate_that_left_its_interval(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "cmp.json").write_text(json.dumps(COMPARISON))
    (bench / "same.json").write_text(json.dumps({**COMPARISON, "new": "results/carracing-quick", "outside": []}))
    page = _page(tmp_path, "bench-compare cmp.json same.json")
    build(tmp_path, registry=tmp_path / "results")
    text = page.read_text()
    assert (
        "| [`cmp.json`](../results/bench/cmp.json) | `results/fetch-quick` against "
        "`at-abc1234/results/fetch-quick` | 3 | 2 | 1 |" in text
    )
    assert "| 3 | 0 | 1 |" in text
    moved = " ".join(text.split("- `results/fetch-quick`: ", 1)[1].split("<!--")[0].split())
    assert moved == (
        "eval/mdm.csv success of `ridge`: 1/20 -> 10/20; benchmark/queries.csv success of `dagger` "
        "(setting 1, demonstration share 1.0): 3/10 -> 1/10."
    )
    assert "results/carracing-quick`:" not in text  # a comparison with nothing outside lists no rate


def test_a_numerics_or_compare_record_without_its_fields_is_one_error_line(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "short.json").write_text(json.dumps({"task": "fetch"}))
    for spec, needle in (
        ("bench-numerics short.json", "results/bench/short.json lacks one of task, width"),
        ("bench-compare short.json", "results/bench/short.json lacks one of new, old"),
        ("bench-numerics", "bench-numerics needs at least one record"),
        ("bench-compare gone.json", "results/bench/gone.json does not exist"),
    ):
        assert needle in _error_line(tmp_path, spec)


STEP = {
    "run": "/somewhere/runs/carracing-quick",
    "seed": 9000,
    "width": 32,
    "env_steps": 1000,
    "trunk_forwards": 100,
    "trunk_rows": 1250,
    "per_env_step_ms": {
        "env_step": 2.0,
        "expert_labels": 0.5,
        "trunk_forward": 1.0,
        "rest_of_the_step": 0.5,
        "lanes_step": 4.0,
        "head_fits": 0.25,
    },
    "step_over_env": 2.0,
    "machine": {"load_avg_1min": 2.04},
}


def test_a_step_block_has_each_part_its_share_and_the_step_over_the_envs_own(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "step.json").write_text(json.dumps(STEP))
    page = _page(tmp_path, "bench-step step.json")
    build(tmp_path, registry=tmp_path / "results")
    lines = page.read_text().splitlines()
    assert "| the env's own step (physics and rendering) | 2.00 | 50% |  |" in lines
    assert "| pi*'s trunk, one forward for the live lanes | 1.00 | 25% |  |" in lines
    assert "| **a laned step** | 4.00 | 100% | 2.00x |" in lines
    assert "| head-only fits between rollouts (beside the step) | 0.25 | - |  |" in lines
    note = " ".join(page.read_text().split("*From ", 1)[1].split())
    assert note.startswith("[`step.json`](../results/bench/step.json): benchmark seed 9000 of `carracing-quick`")
    assert "1,000 env steps, 100 trunk forwards on 1,250 rows (20% of them padding); the 1-minute load" in note


def test_a_step_record_without_its_parts_is_one_error_line(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "flat.json").write_text(json.dumps({**STEP, "per_env_step_ms": {"env_step": 1.0}}))
    (bench / "short.json").write_text(json.dumps({"seed": 1}))
    assert "results/bench/flat.json lacks a part of the step" in _error_line(tmp_path, "bench-step flat.json")
    assert "results/bench/short.json lacks one of per_env_step_ms" in _error_line(tmp_path, "bench-step short.json")


LANES = {
    "run": "runs/fetch-quick",
    "seed": 10040,
    "widths": {
        "1": {"wall_seconds": 21.0, "worker_peak_rss_mb": 745.0},
        "16": {"wall_seconds": 20.5, "worker_peak_rss_mb": 2228.0},
        "8": {"wall_seconds": 19.8, "worker_peak_rss_mb": 1390.0},
    },
    "speedup_wall": {"1": 1.0, "16": 1.0244, "8": 1.0606},
}
PAIRS = {
    "seeds": 40,
    "seconds": {"1": 66.1, "2": 31.7},
    "lanes": {"20": {"seconds": 30.7}},
    "lanes_speedup": {"20": 1.031},
}


def test_a_lanes_block_has_a_row_per_width_of_a_benchmark_seed_and_of_the_pairs(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "lanes.json").write_text(json.dumps(LANES))
    (bench / "pairs.json").write_text(json.dumps(PAIRS))
    page = _page(tmp_path, "bench-lanes lanes.json pairs.json")
    build(tmp_path, registry=tmp_path / "results")
    rows = [line for line in page.read_text().splitlines() if line.startswith("| [`")]
    lanes, pairs = "[`lanes.json`](../results/bench/lanes.json)", "[`pairs.json`](../results/bench/pairs.json)"
    assert rows == [  # widths in numeric order, the pairs' width 1 at 2 workers first
        f"| {lanes} | benchmark seed 10040, one process | 1 | 21.0 | 1.00x | 745 MB |",
        f"| {lanes} | benchmark seed 10040, one process | 8 | 19.8 | 1.06x | 1,390 MB |",
        f"| {lanes} | benchmark seed 10040, one process | 16 | 20.5 | 1.02x | 2,228 MB |",
        f"| {pairs} | 40 pair seeds, 2 workers | 1 | 31.7 | 1.00x | - |",
        f"| {pairs} | 40 pair seeds, 2 workers | 20 | 30.7 | 1.03x | - |",
    ]


def test_a_lanes_record_without_its_widths_is_one_error_line(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "bare.json").write_text(json.dumps({"seeds": 4}))
    assert "results/bench/bare.json lacks one of seeds, seconds, lanes, lanes_speedup" in _error_line(
        tmp_path, "bench-lanes bare.json"
    )
    assert "bench-lanes needs at least one record" in _error_line(tmp_path, "bench-lanes")


FIT = {
    "task": "carracing",
    "preset": "quick",
    "batch_size": 64,
    "batch_shards": 1,
    "cpu_s_per_step": 0.0354,
    "cpu_s_per_step_at_shards": {"1": 0.0333, "2": 0.0163},
    "speedup_over_fewest_shards": {"1": 1.0, "2": 2.043},
    "cpu_time_shares": {"convolutions_forward": 0.24, "convolutions_backward": 0.52, "rest": 0.24},
}


def test_a_fit_block_has_a_row_per_record_with_each_shards_step_its_shares_and_the_gpus_step(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "fit.json").write_text(json.dumps(FIT))
    gpu = {**FIT, "task": "fetch", "batch_shards": 2, "gpu_s_per_step": 0.002, "gpu_speedup": 17.7}
    del gpu["cpu_s_per_step_at_shards"], gpu["speedup_over_fewest_shards"], gpu["cpu_time_shares"]
    (bench / "gpu.json").write_text(json.dumps(gpu))
    page = _page(tmp_path, "bench-fit fit.json gpu.json")
    build(tmp_path, registry=tmp_path / "results")
    rows = [line for line in page.read_text().splitlines() if line.startswith("| [`")]
    fit, on_gpu = "[`fit.json`](../results/bench/fit.json)", "[`gpu.json`](../results/bench/gpu.json)"
    assert rows == [
        f"| {fit} | `carracing` quick | 64 | 1 | 33.3 at 1 (1.00x), 16.3 at 2 (2.04x) | 24% | 52% | 24% | - |",
        f"| {on_gpu} | `fetch` quick | 64 | 2 | 35.4 at 2 (1.00x) | - | - | - | 2.0 (17.7x the CPU's) |",
    ]


def test_a_fit_record_without_its_step_is_one_error_line(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    (bench / "bare.json").write_text(json.dumps({"task": "fetch"}))
    assert "results/bench/bare.json lacks one of task, preset, batch_size, batch_shards, cpu_s_per_step" in (
        _error_line(tmp_path, "bench-fit bare.json")
    )
    assert "bench-fit needs at least one record" in _error_line(tmp_path, "bench-fit")


def test_an_env_block_has_a_row_per_record_with_each_step_time_over_the_others(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    record = {
        "ours": {"id": "metadagger/CarRacing-v0+faults", "steps_per_s": 900.0},
        "upstream": {"id": "metadagger/CarRacing-v0", "steps_per_s": 1000.0},
        "ratio": 0.9,
        "ratio_of_medians": 0.8,
        "identical_rewards": False,
        "machine": {"load_avg_1min": 2.04},
    }
    (bench / "faults.json").write_text(json.dumps(record))
    page = _page(tmp_path, "bench-env faults.json")
    build(tmp_path)
    text = page.read_text()
    assert (
        "| `metadagger/CarRacing-v0+faults` | `metadagger/CarRacing-v0` | 900 / 1000 | 1.11x | 1.25x | no | 2.0 |"
        in text
    )
    (bench / "faults.json").write_text(json.dumps({"ours": {}}))
    result = runner.invoke(app, ["results", "build", "--root", str(tmp_path)])
    assert result.exit_code == 2 and "results/bench/faults.json lacks one of ours, upstream, ratio" in result.output


def test_an_expert_block_names_the_command_and_reads_the_records_rows(tmp_path):
    bench = tmp_path / "results" / "bench"
    bench.mkdir(parents=True)
    rows = [
        {"seed": 0, "success": True, "reward": 900.0, "steps": 800},
        {"seed": 1, "success": True, "reward": 920.0, "steps": 700},
    ]
    command = "metadagger expert --task carracing-echo --preset paper --seeds 0-1"
    (bench / "expert.json").write_text(json.dumps({"command": command, "rows": rows}))
    page = _page(tmp_path, "bench-expert expert.json")
    build(tmp_path)
    text = page.read_text()
    assert f"`{command}` ([`expert.json`](../results/bench/expert.json)):" in " ".join(text.split())
    assert "| 2 | 2 | 100.0% (34%-100%) | 910.0 | 700 / 750.0 / 800 |" in text
    (bench / "expert.json").write_text(json.dumps({"rows": rows}))
    assert "results/bench/expert.json lacks one of command, rows" in _error_line(tmp_path, "bench-expert expert.json")
