"""pi* and per-seed pairs on the toy corridor task: artifacts, resume, determinism, executors."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from toy_task import CorridorTask

from metadagger.errors import CheckpointError, UserError
from metadagger.evaluation.report.run import pistar_section
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.rollouts import rollout
from metadagger.metal_dagger.method import seed_context
from metadagger.metal_dagger.pairs import PairConfig, collect_pairs, is_kept
from metadagger.metal_dagger.pistar import (
    PiStarConfig,
    head_from_pistar,
    pistar_changes,
    train_pistar,
)
from metadagger.metal_dagger.store import PairStore
from metadagger.policies import load_policy
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import stamp_of

TESTS = Path(__file__).resolve().parents[1]
# Subprocesses and Ray workers import the toy tasks from here; the caller's PYTHONPATH (e.g. a
# source checkout) is kept, so they import the same metadagger as this process.
PYTHONPATH = os.pathsep.join([str(TESTS), str(TESTS / "metal_dagger"), *filter(None, [os.environ.get("PYTHONPATH")])])
GT = PiStarConfig(
    seeds=(0, 1, 2, 3), eval_seeds=(100, 101), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3)
)
PAIRS = PairConfig(
    seeds=tuple(range(200, 206)),
    dagger_rounds=1,
    keep="all",
    bc=BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True),
    dagger_bc=BCConfig(lr=1e-2, batch_size=10, epochs=2, head_only=True),
)


def pistar_path(run: Path) -> Path:
    return RunLayout(run).pistar


def with_pistar(gt_run: Path, run: Path) -> RunLayout:
    """A fresh run folder holding a copy of ``gt_run``'s pi*."""
    layout = RunLayout(run)
    layout.pistar_dir.mkdir(parents=True)
    layout.pistar.write_bytes(pistar_path(gt_run).read_bytes())
    return layout


@pytest.fixture(scope="module")
def gt_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("run")
    train_pistar(CorridorTask(), GT, RunLayout(run), progress=False)
    return run


def test_pistar_in_lanes_does_not_depend_on_workers_and_is_not_taken_for_pistar_made_alone(tmp_path):
    laned = dataclasses.replace(GT, lanes=3)
    one, two = RunLayout(tmp_path / "one"), RunLayout(tmp_path / "two")
    metrics = train_pistar(CorridorTask(), laned, one, progress=False)
    assert train_pistar(CorridorTask(), laned, two, progress=False, workers=2) == metrics
    assert one.pistar.read_bytes() == two.pistar.read_bytes()
    assert any("lanes" in change for change in pistar_changes(CorridorTask(), GT, one))
    with pytest.raises(UserError, match="pistar.lanes must be an integer from 1 to 256, got 0"):
        dataclasses.replace(GT, lanes=0)


def test_pistar_writes_policy_metrics_and_round_checkpoints(gt_run):
    assert pistar_path(gt_run).is_file()
    assert (gt_run / "pistar" / "metrics.json").is_file()
    assert sorted(p.name for p in (gt_run / "pistar" / "rounds").iterdir()) == [
        "round_0.safetensors",
        "round_1.safetensors",
    ]
    assert load_policy(pistar_path(gt_run)).head_size == 32 * 3 + 3
    # every fit's loss per epoch, for the TensorBoard curves; the last is the round's final loss
    metrics = json.loads((gt_run / "pistar" / "metrics.json").read_text())
    assert len(metrics["bc_epoch_losses"]) == GT.bc.epochs
    assert [len(r["dagger/epoch_losses"]) for r in metrics["rounds"]] == [GT.bc.epochs] * GT.dagger_rounds
    assert all(r["dagger/epoch_losses"][-1] == r["dagger/final_loss"] for r in metrics["rounds"])


def test_pistar_resumes_from_round_checkpoints(gt_run, tmp_path):
    # a run killed after its last fit: the checkpoints are there, the final policy is not
    (tmp_path / "pistar").mkdir()
    for src in (gt_run / "pistar" / "rounds").iterdir():
        (tmp_path / "pistar" / "rounds").mkdir(exist_ok=True)
        (tmp_path / "pistar" / "rounds" / src.name).write_bytes(src.read_bytes())
    (tmp_path / "pistar" / "stamp.json").write_bytes((gt_run / "pistar" / "stamp.json").read_bytes())
    metrics = train_pistar(CorridorTask(), GT, RunLayout(tmp_path), progress=False)
    assert all(r["dagger/final_loss"] is None for r in metrics["rounds"])  # nothing refitted
    assert metrics["bc_epoch_losses"] is None and all(r["dagger/epoch_losses"] is None for r in metrics["rounds"])
    assert pistar_path(tmp_path).read_bytes() == pistar_path(gt_run).read_bytes()


def test_a_damaged_finished_pistar_is_named_and_retrained_once_deleted(gt_run, tmp_path):
    shutil.copytree(gt_run, tmp_path / "run")
    layout = RunLayout(tmp_path / "run")
    intact = layout.pistar.read_bytes()
    layout.pistar.write_bytes(intact[:100])
    with pytest.raises(
        CheckpointError, match=f"policy checkpoint is corrupt or not a safetensors file: {layout.pistar}"
    ):
        train_pistar(CorridorTask(), GT, layout, rebuild=True, progress=False)
    layout.pistar.unlink()
    train_pistar(CorridorTask(), GT, layout, progress=False)
    assert layout.pistar.read_bytes() == intact


def test_keep_rules():
    assert is_kept("bc_fail_da_success", False, True)
    assert not is_kept("bc_fail_da_success", True, True)
    assert is_kept("da_success", True, True) and not is_kept("da_success", True, False)
    assert is_kept("all", False, False)


def test_pairs_are_stored_summarised_and_byte_identical_across_runs(gt_run, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for run in (a, b):
        summary = collect_pairs(
            CorridorTask(), with_pistar(gt_run, run), PAIRS, StageOptions(workers=2, progress=False)
        )
    assert summary["seeds"] == len(PAIRS.seeds) and summary["kept"] == len(PAIRS.seeds)
    assert sum(summary["outcomes"].values()) == len(PAIRS.seeds)
    for seed in PAIRS.seeds:
        assert (a / "pairs" / f"{seed}.safetensors").read_bytes() == (b / "pairs" / f"{seed}.safetensors").read_bytes()
    records = PairStore(a / "pairs").records()
    assert {r["seed"] for r in records} == set(PAIRS.seeds)
    assert all(r["bc"]["expert_queries"] > 0 and r["da"]["expert_queries"] > r["bc"]["expert_queries"] for r in records)


def test_pairs_in_lanes_do_not_depend_on_workers_blocks_or_resume(gt_run, tmp_path):
    """Pair seeds made in blocks of lanes: the same files with 1 or 3 workers, for a seed made
    alone, and after a run that stopped with part of the seeds done."""
    laned = dataclasses.replace(PAIRS, lanes=4)  # 6 seeds: two blocks of 3 (three of 2 for 3 workers)
    one, two, resumed = tmp_path / "one", tmp_path / "two", tmp_path / "resumed"
    collect_pairs(CorridorTask(), with_pistar(gt_run, one), laned, StageOptions(workers=1, progress=False))
    collect_pairs(CorridorTask(), with_pistar(gt_run, two), laned, StageOptions(workers=3, progress=False))
    layout = with_pistar(gt_run, resumed)
    collect_pairs(
        CorridorTask(), layout, dataclasses.replace(laned, seeds=(203,)), StageOptions(workers=1, progress=False)
    )
    collect_pairs(CorridorTask(), layout, laned, StageOptions(workers=1, progress=False))
    for seed in PAIRS.seeds:
        mine = (one / "pairs" / f"{seed}.safetensors").read_bytes()
        assert mine == (two / "pairs" / f"{seed}.safetensors").read_bytes()
        assert mine == (resumed / "pairs" / f"{seed}.safetensors").read_bytes()
    assert {r["seed"] for r in PairStore(one / "pairs").records()} == set(PAIRS.seeds)
    alone = tmp_path / "alone"
    collect_pairs(CorridorTask(), with_pistar(gt_run, alone), PAIRS, StageOptions(workers=1, progress=False))
    # lanes are a setting of the pairs: pairs made alone are not taken for pairs made in lanes
    with pytest.raises(UserError, match="lanes"):
        collect_pairs(CorridorTask(), RunLayout(alone), laned, StageOptions(workers=1, progress=False))
    with pytest.raises(UserError, match="pairs.lanes must be an integer from 1 to 256, got 0"):
        dataclasses.replace(PAIRS, lanes=0)


def test_a_damaged_pistar_is_named_before_any_pair_is_touched(gt_run, tmp_path):
    first = PairConfig(**{**PAIRS.__dict__, "seeds": PAIRS.seeds[:2]})
    layout = with_pistar(gt_run, tmp_path)
    collect_pairs(CorridorTask(), layout, first, StageOptions(workers=1, progress=False))
    before = {p.name: p.read_bytes() for p in (tmp_path / "pairs").iterdir()}
    layout.pistar.write_bytes(layout.pistar.read_bytes()[:100])
    with pytest.raises(CheckpointError, match=f"corrupt or not a safetensors file: {layout.pistar}"):
        collect_pairs(CorridorTask(), layout, PAIRS, StageOptions(workers=1, progress=False))
    assert {p.name: p.read_bytes() for p in (tmp_path / "pairs").iterdir()} == before


def test_pairs_skip_seeds_already_stored(gt_run, tmp_path):
    first = PairConfig(**{**PAIRS.__dict__, "seeds": PAIRS.seeds[:2]})
    layout = with_pistar(gt_run, tmp_path)
    collect_pairs(CorridorTask(), layout, first, StageOptions(workers=1, progress=False))
    stamps = {s: (tmp_path / "pairs" / f"{s}.safetensors").stat().st_mtime_ns for s in first.seeds}
    collect_pairs(CorridorTask(), layout, PAIRS, StageOptions(workers=1, progress=False))
    assert {s: (tmp_path / "pairs" / f"{s}.safetensors").stat().st_mtime_ns for s in first.seeds} == stamps
    assert PairStore(tmp_path / "pairs").done_seeds() == set(PAIRS.seeds)


_KILLABLE = """
import signal, sys
# a shell's background job starts with SIGINT ignored: restore Python's handler (see test_executors)
signal.signal(signal.SIGINT, signal.default_int_handler)
from slow_task import SlowCorridorTask
from metadagger.runfolder.layout import RunLayout
from metadagger.metal_dagger.pairs import collect_pairs
from metadagger.runfolder.driver import StageOptions
from test_pistar_pairs import PAIRS
collect_pairs(SlowCorridorTask(), RunLayout(sys.argv[1]), PAIRS, StageOptions(workers=1, progress=False))
"""


@pytest.mark.parametrize(
    "sig",
    # SIGINT's path (KeyboardInterrupt through the driver) is also the command line's, tested in tests/cli
    [signal.SIGKILL, pytest.param(signal.SIGINT, marks=pytest.mark.slow)],
    ids=["SIGKILL", "SIGINT"],
)
def test_killed_pairs_run_resumes_without_redoing_or_losing_seeds(gt_run, tmp_path, sig):
    env = {**os.environ, "PYTHONPATH": PYTHONPATH}
    with_pistar(gt_run, tmp_path)
    cmd = [sys.executable, "-c", _KILLABLE, str(tmp_path)]
    proc = subprocess.Popen(cmd, env=env, start_new_session=True)
    store = PairStore(tmp_path / "pairs")
    deadline = time.monotonic() + 60
    while len(store.done_seeds()) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, sig)
    proc.wait(timeout=30)
    finished = store.done_seeds()
    assert 2 <= len(finished) < len(PAIRS.seeds)
    stamps = {s: store.pair_path(s).stat().st_mtime_ns for s in finished}
    subprocess.run(cmd, env=env, check=True, timeout=120)
    assert store.done_seeds() == set(PAIRS.seeds)
    assert {s: store.pair_path(s).stat().st_mtime_ns for s in finished} == stamps
    assert len(store.records()) == len(PAIRS.seeds)


def test_ray_executor_pairs_equal_local(gt_run, tmp_path, monkeypatch):
    pytest.importorskip("ray")
    # the local Ray instance's workers inherit this, so they can import the toy task
    monkeypatch.setenv("PYTHONPATH", PYTHONPATH)
    seeds = PairConfig(**{**PAIRS.__dict__, "seeds": PAIRS.seeds[:3]})
    collect_pairs(
        CorridorTask(), with_pistar(gt_run, tmp_path / "local"), seeds, StageOptions(workers=2, progress=False)
    )
    collect_pairs(
        CorridorTask(),
        with_pistar(gt_run, tmp_path / "ray"),
        seeds,
        StageOptions(executor="ray", workers=2, progress=False),
    )
    for seed in seeds.seeds:
        assert (tmp_path / "local" / "pairs" / f"{seed}.safetensors").read_bytes() == (
            tmp_path / "ray" / "pairs" / f"{seed}.safetensors"
        ).read_bytes()


def test_each_pair_stores_its_seed_context_from_the_demonstration_and_the_bc_rollout(gt_run, tmp_path):
    """The context is the mean trunk feature of the demonstration and of DAgger's first rollout
    (the BC head's, under the pairs' early stop): the same numbers evaluation computes afresh."""
    layout = with_pistar(gt_run, tmp_path)
    collect_pairs(CorridorTask(), layout, PAIRS, StageOptions(workers=1, progress=False))
    store = PairStore(layout.pairs_dir)
    seed = PAIRS.seeds[0]
    stored = store.load_contexts([seed])[0]
    policy = head_from_pistar(load_policy(layout.pistar), PAIRS.bc.head_init_seed(seed))
    demo = collect(CorridorTask(), [seed], policy=None)[0].to_dataset()
    cache = FeatureCache(policy)
    fit_bc(policy, demo, dataclasses.replace(PAIRS.bc, seed=seed), cache=cache)
    stop = None if PAIRS.early_stop is None else CosineEarlyStop(threshold=PAIRS.early_stop)
    unlabelled = rollout(CorridorTask().make_env(), seed=seed, policy=policy, early_stop=stop)
    assert torch.equal(stored, torch.from_numpy(seed_context(cache, demo.obs, unlabelled.obs)))
    assert stored.shape == (2 * policy.net.feature_dim,)
    split = store.load_split(val_fraction=0.2, seed=0, kept_only=False)
    assert split.context_train.shape == (len(split.train_seeds), stored.shape[0])
    assert torch.equal(
        split.context_train[split.train_seeds.index(seed)]
        if seed in split.train_seeds
        else split.context_val[split.val_seeds.index(seed)],
        stored,
    )


def test_pistar_can_choose_its_bc_epoch_on_held_out_seeds(tmp_path):
    config = dataclasses.replace(GT, dagger_rounds=0, select_seeds=(200, 201, 202, 203), select_every=2)
    metrics = train_pistar(CorridorTask(), config, RunLayout(tmp_path), progress=False)
    choice = metrics["bc_selection"]
    assert [check["epoch"] for check in choice["history"]] == [2, 3] and choice["episodes"] == 4
    assert choice["successes"] == max(check["successes"] for check in choice["history"])
    saved, checkpoint = (
        load_policy(pistar_path(tmp_path)),
        load_policy(tmp_path / "pistar" / "rounds" / "round_0.safetensors"),
    )
    assert all(torch.equal(a, b) for a, b in zip(saved.net.parameters(), checkpoint.net.parameters()))
    assert any(
        line.startswith(f"pi* is epoch {choice['epoch']} of its BC fit") for line in pistar_section(RunLayout(tmp_path))
    )
    # the options joined the config later: a pi* made without them keeps its stamp
    assert "select_seeds" not in stamp_of(GT) and "select_every" not in stamp_of(GT)


@pytest.mark.parametrize(
    "changes,match",
    [
        ({"select_seeds": (3, 200)}, "select_seeds must be held out"),
        ({"select_seeds": (101,)}, "select_seeds must be held out"),
        ({"select_seeds": (200,), "dagger_rounds": 1}, "needs dagger_rounds: 0"),
        ({"select_seeds": (200,), "dagger_rounds": 0, "select_every": 0}, "select_every must be an integer >= 1"),
    ],
)
def test_pistar_selection_settings_are_checked(changes, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(GT, **changes)


@pytest.mark.parametrize("refit_from", ["current", "origin"])
def test_a_dagger_refit_starts_from_the_current_head_or_from_the_origin(gt_run, refit_from):
    """``refit_from: origin`` makes every refit BC on the aggregate from the seed's fresh head (so BC
    refitted on the demonstration alone is w_BC itself); ``current`` continues the rolled-out head."""
    from metadagger.imitation.data import Aggregate
    from metadagger.metal_dagger.method import SeedLearner, bc_head, dagger_rounds, demonstration, seeded

    fit = dataclasses.replace(PAIRS.bc, refit_from=refit_from)
    seed = PAIRS.seeds[0]
    with SeedLearner(CorridorTask(), str(pistar_path(gt_run)), seed, head_init_seed=seed) as learner:
        fresh = learner.head()
        demo = demonstration(learner)
        w_bc = bc_head(learner, demo.to_dataset(), seeded(fit, seed))
        first = learner.roll(w_bc)
        rounds = dagger_rounds(
            learner, start=w_bc, first_rollout=first, demo=demo, rounds=1, fit=seeded(fit, seed), origin=fresh
        )
        [round_] = list(rounds)
        learner.load(fresh if refit_from == "origin" else w_bc)
        data = Aggregate([demo.to_dataset(), round_.labelled])
        expected = bc_head(learner, data, seeded(fit, seed))
        assert torch.equal(torch.from_numpy(round_.head), torch.from_numpy(expected))
        if refit_from == "origin":
            learner.load(fresh)
            assert torch.equal(
                torch.from_numpy(bc_head(learner, demo.to_dataset(), seeded(fit, seed))), torch.from_numpy(w_bc)
            )
            with pytest.raises(ValueError, match="needs origin="):
                list(dagger_rounds(learner, start=w_bc, first_rollout=first, demo=demo, rounds=1, fit=fit))


def test_an_unknown_refit_start_is_refused():
    with pytest.raises(UserError, match="BCConfig.refit_from must be one of current, origin, got 'fresh'"):
        BCConfig(refit_from="fresh")
