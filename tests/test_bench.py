"""``bench_env`` times our CarRacing against upstream's (and the Fetch pixel env) and writes JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metadagger.bench import bench_env, smooth_actions, write_bench
from metadagger.errors import UserError


def test_smooth_actions_are_seeded_and_in_range():
    a = smooth_actions(4, 200)
    assert a.shape == (200, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, smooth_actions(4, 200))
    assert not np.array_equal(a, smooth_actions(5, 200))
    assert a[:, 0].min() >= -1 and a[:, 0].max() <= 1 and a[:, 1:].min() >= 0 and a[:, 1:].max() <= 1
    assert np.abs(np.diff(a[:, 0])).mean() < 0.5  # smooth steering


def test_bench_env_reports_both_rates(tmp_path):
    result = bench_env("carracing", seeds=(0,), steps=8, warmup_steps=2)
    assert result["ours"]["id"] == "metadagger/CarRacing-v0" and result["upstream"]["id"] == "CarRacing-v3"
    for side in ("ours", "upstream"):
        assert result[side]["steps_per_s"] > 0
        assert 0 < result[side]["render_us_per_step"] < result[side]["us_per_step"]
    assert result["ratio"] == pytest.approx(result["ours"]["steps_per_s"] / result["upstream"]["steps_per_s"])
    assert result["identical_rewards"] is True
    assert result["seeds"] == [0] and result["steps"] == 8 and result["machine"]["cpu_count"] >= 1
    path = write_bench(result, tmp_path / "bench" / "env.json")
    assert json.loads(path.read_text())["ratio"] == pytest.approx(result["ratio"])


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


def test_bench_bc_times_full_and_head_only_fits():
    from metadagger.bench import bench_bc

    result = bench_bc(images=20, epochs=1)
    assert result["parameters"] > 100_000 and result["head_size"] == 64 * 20 + 20
    assert result["full_fit_s"] > 0 and result["head_only_fit_s"] > 0
    assert result["speedup_incl_features"] == result["full_fit_s"] / (result["head_only_features_s"] + result["head_only_fit_s"])
