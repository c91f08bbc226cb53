"""``bench_env`` times our CarRacing against upstream's (and the Fetch pixel env) and writes JSON."""

from __future__ import annotations

import json
import os
import platform
import shutil

import gymnasium as gym
import numpy as np
import pytest

from metadagger.cli.bench import write_bench
from metadagger.cli.bench_env import bench_env, smooth_actions
from metadagger.errors import UserError
from metadagger.runfolder.driver import StageOptions


def test_smooth_actions_are_seeded_and_in_range():
    a = smooth_actions(4, 200)
    assert a.shape == (200, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, smooth_actions(4, 200))
    assert not np.array_equal(a, smooth_actions(5, 200))
    assert a[:, 0].min() >= -1 and a[:, 0].max() <= 1 and a[:, 1:].min() >= 0 and a[:, 1:].max() <= 1
    assert np.abs(np.diff(a[:, 0])).mean() < 0.5  # smooth steering


def test_bench_env_times_our_env_beside_upstream_on_the_same_actions(tmp_path):
    long = bench_env("carracing", seeds=(0,), steps=200, warmup_steps=20)
    short = bench_env("carracing", seeds=(0,), steps=20, warmup_steps=20)
    assert long["ours"]["id"] == "metadagger/CarRacing-v0" and long["upstream"]["id"] == "CarRacing-v3"
    # the ratios are the benchmark's to report (docs/performance.md), not a test's to assert
    assert long["ratio"] == pytest.approx(long["ours"]["steps_per_s"] / long["upstream"]["steps_per_s"])
    assert long["ratio_of_medians"] > 0
    for side in ("ours", "upstream"):
        # rendering is part of a step, not all of it (physics, rewards, wrappers take the rest)
        assert 0 < long[side]["render_us_per_step"] < long[side]["us_per_step"]
        assert long[side]["other_us_per_step"] > 0
        # ten times the steps take more time in all
        assert long[side]["us_per_step"] * 200 > short[side]["us_per_step"] * 20
    assert long["identical_rewards"] is True and short["identical_rewards"] is True
    assert set(long["image_mae"]) == {"0"} and 0 < long["image_mae"]["0"] < 1.0
    assert long["seeds"] == [0] and long["steps"] == 200 and short["steps"] == 20

    path = write_bench(long, tmp_path / "bench" / "env.json")
    assert json.loads(path.read_text()) == long
    machine = json.loads(path.read_text())["machine"]
    assert machine["cpu_count"] == os.cpu_count() and machine["python"] == platform.python_version()
    assert machine["gymnasium"] == gym.__version__


def test_bench_env_times_the_echo_band_beside_our_carracing():
    """The echo task's env against our CarRacing on the same actions: the same physics and rewards,
    frames that differ in the band alone."""
    echo = bench_env("carracing-echo", seeds=(0,), steps=30, warmup_steps=0)
    assert echo["ours"]["id"] == "metadagger/CarRacing-v0+echo" and echo["upstream"]["id"] == "metadagger/CarRacing-v0"
    assert echo["identical_rewards"] is True
    band = 96 * 6 / (96 * 96)  # the band's share of a frame: at most the whole band differs
    assert 0 < echo["image_mae"]["0"] <= 255 * band


def test_bench_env_times_the_presets_faults_variant_beside_our_carracing():
    """The variant carracing-echo's presets run: a fault moves the car, so its frames part from our
    CarRacing's on the same actions once a fault has struck (the variant has no band)."""
    faults = bench_env("carracing-echo-faults", seeds=(3,), steps=300, warmup_steps=0)
    assert faults["ours"]["id"] == "metadagger/CarRacing-v0+faults"
    assert faults["image_mae"]["3"] > 0 and faults["ratio"] > 0


def test_bench_env_rejects_unknown_task_and_empty_runs():
    with pytest.raises(UserError, match="unknown task 'pong'"):
        bench_env("pong")
    with pytest.raises(UserError, match="steps > 0"):
        bench_env("carracing", steps=0)


def test_bench_env_fetch_reports_frames_per_second():
    pytest.importorskip("gymnasium_robotics")
    result = bench_env("fetch", seeds=(0,), steps=5)
    assert result["task"] == "fetch" and result["steps"] == 5 and result["image_size"] == 64
    assert result["steps_per_second"] > 0 and result["machine"]["cpu_count"] >= 1


def test_bench_bc_times_the_full_fit_and_the_head_only_refit_side_by_side():
    from metadagger.cli.bench import bench_bc

    big = bench_bc(images=200, epochs=3)
    assert big["parameters"] > 100_000 and big["head_size"] == 64 * 20 + 20
    assert big["images"] == 200 and big["epochs"] == 3
    times = big["full_fit_s"], big["head_only_features_s"], big["head_only_fit_s"]
    assert min(times) > 0  # the ratios are the benchmark's to report, not a test's to assert
    assert big["speedup_cached_refit"] == pytest.approx(big["full_fit_s"] / big["head_only_fit_s"])
    assert big["speedup_incl_features"] == pytest.approx(
        big["full_fit_s"] / (big["head_only_features_s"] + big["head_only_fit_s"])
    )
    assert 0 < big["inference_ms_batch1"] < 1000


def test_bench_fit_times_pistars_fit_on_the_cpu_and_a_gpu_where_there_is_one():
    import torch

    from metadagger.cli.bench import bench_fit

    result = bench_fit("carracing", preset="ci", steps=2, shards=(2, 1))
    assert result["task"] == "carracing" and result["steps"] == 2 and result["cpu_s_per_step"] > 0
    assert ("gpu_speedup" in result) == torch.cuda.is_available()
    assert list(result["cpu_s_per_step_at_shards"]) == ["1", "2"]  # in order, the speed-ups over 1 shard
    assert result["speedup_over_fewest_shards"]["1"] == 1.0
    shares = result["cpu_time_shares"]
    assert set(shares) == {"convolutions_forward", "convolutions_backward", "rest"}
    assert sum(shares.values()) == pytest.approx(1.0) and shares["convolutions_backward"] > 0
    assert "load_avg_1min" in result["machine"]


def test_bench_fit_refuses_a_shard_count_below_1_before_any_work():
    from metadagger.cli.bench import bench_fit

    with pytest.raises(UserError, match="--shards must be integers >= 1, got 0"):
        bench_fit("carracing", preset="ci", steps=2, shards=(0,))


def test_bench_prior_times_prior_fits_beside_plain_ones():
    from metadagger.cli.bench import bench_prior

    result = bench_prior(fits=3, rows=20, epochs=2, repeats=1)
    assert result["head_size"] == 20 * 65
    for count in ("fits_1", "fits_3"):
        timing = result[count]
        assert timing["plain_s"] > 0 and timing["prior_over_plain"] == timing["prior_s"] / timing["plain_s"]


def test_bench_pairs_times_workers_without_touching_the_run(tmp_path):
    from toy_task import TINY_PRESETS, RunCorridorTask

    from metadagger.cli.bench import bench_pairs
    from metadagger.pipeline.run_config import init_run
    from metadagger.pipeline.stages import stage_pistar
    from metadagger.runfolder.layout import RunLayout
    from metadagger.tasks import _FACTORIES, register_task

    register_task("corridor-bench", RunCorridorTask)
    try:
        presets = tmp_path / "presets.yaml"
        presets.write_text(TINY_PRESETS)
        run = tmp_path / "run"
        stage_pistar(RunLayout(run), init_run(run, "corridor-bench", "tiny", presets), StageOptions(progress=False))

        result = bench_pairs(run, seeds=3, workers=(1, 2), target_kept=10, nodes=(4,), lanes=(2,))
        assert not (run / "pairs").exists()  # collected into temporary stores only
        assert set(result["seconds"]) == {"1", "2"} and all(t > 0 for t in result["seconds"].values())
        assert all(r > 0 for r in result["pairs_per_hour"].values())
        # keep: all, so every pair the bench collected is kept, and a target is reachable
        assert result["kept_share"] == 1.0 and result["kept_share_from"] == "bench"
        assert result["minutes_for_target_kept"] > 0
        hours = result["extrapolated"]["hours_on_ray_nodes"]
        assert hours["1"] == pytest.approx(result["minutes_for_target_kept"] / 60) and hours["4"] == pytest.approx(
            hours["1"] / 4
        )
        assert result["extrapolated"]["pair_seeds_for_target_kept"] == 10
        assert result["machine"]["cpu_count"] == os.cpu_count()
        assert result["lanes"]["2"]["workers"] == 2 and result["lanes"]["2"]["pairs_per_hour"] > 0
        assert result["lanes"]["2"]["block_sizes"] == [1, 2]  # one block per worker, as even as can be
        # lanes against the same seeds one at a time with as many workers, whatever the run sets
        assert result["lanes_speedup"]["2"] == pytest.approx(result["seconds"]["2"] / result["lanes"]["2"]["seconds"])
        assert result["run_pairs_lanes"] == 1
        fastest = max(result["pairs_per_hour"]["2"], result["lanes"]["2"]["pairs_per_hour"])
        assert result["minutes_for_target_kept"] == pytest.approx(60.0 * 10 / fastest)

        # with a pairs summary in the run, its kept share is used
        (run / "pairs").mkdir()
        (run / "pairs" / "summary.json").write_text(json.dumps({"seeds": 4, "kept": 1}))
        from_run = bench_pairs(run, seeds=1, workers=(1,))
        assert from_run["kept_share"] == 0.25 and from_run["kept_share_from"] == "run"
        assert from_run["seconds"]["1"] > 0

        with pytest.raises(UserError, match="1 <= --seeds <= 4"):
            bench_pairs(run, seeds=5)
        with pytest.raises(UserError, match="bench pairs --lanes must be an integer from 1 to 256, got 0"):
            bench_pairs(run, seeds=1, lanes=(0,))
        with pytest.raises(UserError, match="--target-kept >= 1 and --nodes >= 1"):
            bench_pairs(run, seeds=1, nodes=(0,))
        # 3 seeds for 2 workers: blocks of 1 and 2 lanes, under half a width of 4
        with pytest.raises(UserError, match="--lanes 4 cuts --seeds 3 into blocks of 1 lanes .*give --seeds 8 for"):
            bench_pairs(run, seeds=3, lanes=(4,))
    finally:
        del _FACTORIES["corridor-bench"]


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_bench_lanes_times_one_benchmark_seed_at_each_width_without_touching_the_run(carracing_ci_run, tmp_path):
    from metadagger.cli.bench_lanes import bench_lanes

    run = tmp_path / "run"
    shutil.copytree(carracing_ci_run, run)
    before = (run / "benchmark" / "rows.jsonl").read_bytes()
    result = bench_lanes(run, widths=(1, 4), repeats=2)
    assert (run / "benchmark" / "rows.jsonl").read_bytes() == before
    # the ci preset names seeds up to 10000 (pi*'s unseen check): the timed seed is none of the run's
    assert result["seed"] == 10001 and set(result["widths"]) == {"1", "4"} and result["repeats"] == 2
    for timing in result["widths"].values():
        assert timing["wall_seconds"] > 0 and timing["worker_cpu_seconds"] > 0 and timing["worker_peak_rss_mb"] > 50
        assert len(timing["rows_sha256"]) == 64 and timing["same_rows"] and len(timing["each"]) == 2
        assert timing["worker_peak_rss_mb"] == max(r["worker_peak_rss_mb"] for r in timing["each"])
    assert result["speedup_wall"]["1"] == 1.0 and result["speedup_wall"]["4"] > 0
    with pytest.raises(UserError, match="--lanes from 1 to 256"):
        bench_lanes(run, widths=(0,))
    with pytest.raises(UserError, match="--repeats of at least 1, got 0"):
        bench_lanes(run, widths=(1,), repeats=0)


def test_bench_reproduce_names_a_bad_request_before_any_work():
    from metadagger.cli.bench_reproduce import bench_reproduce

    with pytest.raises(UserError, match="give at least one --set"):
        bench_reproduce("carracing", preset="ci")
    with pytest.raises(UserError, match="pairs.lanes must be an integer from 1 to 256, got 0"):
        bench_reproduce("carracing", preset="ci", overrides=("pairs.lanes=0",))
    with pytest.raises(UserError, match="unknown preset"):
        bench_reproduce("carracing", preset="nope", overrides=("pairs.lanes=2",))


@pytest.mark.slow  # two whole ci runs
def test_bench_reproduce_times_the_preset_and_its_overrides_side_by_side():
    from metadagger.cli.bench_reproduce import ARMS, TABLES, bench_reproduce

    result = bench_reproduce("carracing", preset="ci", overrides=("benchmark.lanes=4",), workers=2, progress=False)
    preset, laned = (result["arms"][arm] for arm in ARMS)
    assert result["speedup"] == pytest.approx(preset["seconds"] / laned["seconds"])
    assert set(preset["stages"]) >= {"pistar", "pairs", "benchmark"} and preset["peak_memory_mb"] > 100
    # the lanes move the benchmark's last bits, nothing before it
    assert preset["sha256"][TABLES[0]] == laned["sha256"][TABLES[0]]


def test_bench_step_takes_a_laned_step_apart_without_touching_the_run(carracing_ci_run, tmp_path):
    from metadagger.cli.bench_lanes import bench_step

    run = tmp_path / "run"
    shutil.copytree(carracing_ci_run, run)
    before = (run / "benchmark" / "rows.jsonl").read_bytes()
    result = bench_step(run, width=4, overrides=("benchmark.methods=[bc, dagger]",))
    assert (run / "benchmark" / "rows.jsonl").read_bytes() == before
    assert (result["seed"], result["width"]) == (10001, 4) and result["env_steps"] > 0 and result["trunk_forwards"] > 0
    assert result["trunk_rows"] == 4 * result["trunk_forwards"] >= result["env_steps"]  # no smaller shape at width 4
    seconds = result["seconds"]
    parts = seconds["env_step"] + seconds["expert_labels"] + seconds["trunk_forward"] + result["rest_of_the_step"]
    assert parts == pytest.approx(seconds["lanes_step"]) and min(seconds.values()) > 0
    assert result["step_over_env"] == pytest.approx(seconds["lanes_step"] / seconds["env_step"])
    assert seconds["env_step_outside_lanes"] > 0  # the demonstrations: not in the step's ratio
    assert result["step_over_env"] > 1
    assert result["per_env_step_ms"]["env_step"] == pytest.approx(1000 * seconds["env_step"] / result["env_steps"])
    with pytest.raises(UserError, match="bench step needs --lanes from 1 to 256"):
        bench_step(run, width=0)
