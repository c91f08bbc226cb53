"""DART at DAgger's labels (Laskey et al. 2017): the expert's perturbed episodes labelled up to each
of plain DAgger's cumulative label counts, w_BC refitted on them and the demonstration."""

from __future__ import annotations

import dataclasses

import pytest
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.protocol import run_benchmark
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.data import Aggregate
from metadagger.imitation.rollouts import ActionNoise
from metadagger.metal_dagger.controls import _first_rows
from metadagger.metal_dagger.method import SeedLearner, bc_head, demonstration, seeded
from metadagger.runfolder.driver import StageOptions

BC = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
SEEDS = (300, 301)
ROUNDS = 2
CONFIG = BenchmarkConfig(seeds=SEEDS, methods=("bc", "dagger", "dart"), dart_noise=0.4)


def _run(layout, config: BenchmarkConfig = CONFIG, **options) -> list[dict]:
    return run_benchmark(
        CorridorTask(),
        layout,
        config,
        rounds=ROUNDS,
        bc=BC,
        dagger_bc=BC,
        early_stop=None,
        kinds=(),
        mdi=None,
        meta_queries={"pistar": 900, "pairs": 100},
        options=StageOptions(**{"workers": 1, "progress": False, **options}),
    )


@pytest.fixture(scope="module")
def rows(toy_run) -> list[dict]:
    return _run(toy_run)


def test_dart_spends_daggers_labels_after_each_round_on_perturbed_episodes(rows):
    table = {(r["method"], r["setting"], r["seed"]): r for r in rows}
    for seed in SEEDS:
        demo = table["bc", "", seed]["expert_queries"]
        for r in range(1, ROUNDS + 1):
            dart, dagger = table["dart", str(r), seed], table["dagger", str(r), seed]
            assert dart["expert_queries"] == dagger["expert_queries"] > demo
            records = dart["labels"]
            assert records[0] == {"round": 0, "runs": [[0, demo]], "scores": None}
            steps = [run[1] - run[0] for record in records[1:] for run in record["runs"]]
            assert sum(steps) == dart["expert_queries"] - demo
            assert all(record["runs"][0][0] == 0 for record in records[1:])  # each episode from its start
            assert dart["takeovers"] == dart["episodes_asked"] == len(records)
            assert [record["round"] for record in records[1:]] == sorted(record["round"] for record in records[1:])


def test_dart_is_w_bc_refitted_on_the_demonstration_and_the_perturbed_labels_as_often_as_dagger(toy_run, rows):
    table = {(r["method"], r["setting"], r["seed"]): r for r in rows}
    seed = SEEDS[0]
    with SeedLearner(CorridorTask(), str(toy_run.pistar), seed, head_init_seed=BC.head_init_seed(seed)) as learner:
        fresh = learner.head()
        demo = demonstration(learner)
        w_bc = bc_head(learner, demo.to_dataset(), seeded(BC, seed))
        episodes = []
        for r in range(1, ROUNDS + 1):
            budget = table["dagger", str(r), seed]["expert_queries"] - demo.steps
            while sum(e.steps for e in episodes) < budget:
                episodes.append(learner.demonstrate(ActionNoise(0.4, stream=(seed, len(episodes)))))
            parts, room = [], budget
            for e in episodes:
                parts.append(_first_rows(e.to_dataset(), min(room, e.steps)))
                room -= len(parts[-1])
                if room == 0:
                    break
            data = Aggregate([demo.to_dataset(), *parts])
            learner.load(w_bc)
            for _ in range(r):
                learner.start_refit(BC, fresh)
                bc_head(learner, data, seeded(BC, seed))
            rolled = learner.roll()
            row = table["dart", str(r), seed]
            assert (rolled.reward, rolled.steps, bool(rolled.success)) == (row["reward"], row["steps"], row["success"])


def test_dart_rows_stamp_their_noise_and_are_made_again_when_it_changes(toy_run, rows, tmp_path):
    import shutil

    from metadagger.runfolder.layout import RunLayout

    shutil.copytree(toy_run.root, tmp_path / "run")
    layout = RunLayout(tmp_path / "run")
    again = _run(layout)
    assert [(r["method"], r["setting"], r["seed"], r["reward"]) for r in again] == [
        (r["method"], r["setting"], r["seed"], r["reward"]) for r in rows
    ]
    louder = dataclasses.replace(CONFIG, dart_noise=0.9)
    with pytest.raises(UserError, match=r"'dart@1' on 2 seed\(s\) .* \(dart_noise: 0.4 -> 0.9\)"):
        _run(layout, louder)
    remade = {(r["method"], r["setting"], r["seed"]): r for r in _run(layout, louder, rebuild=True)}
    kept = {(r["method"], r["setting"], r["seed"]): r for r in rows}
    assert remade.keys() == kept.keys()
    assert all(remade[k] == kept[k] for k in kept if k[0] != "dart")
    assert any(remade[k]["labels"] != kept[k]["labels"] for k in kept if k[0] == "dart")


def test_dart_needs_dagger_and_a_noise_scale():
    with pytest.raises(UserError, match="benchmark.methods has dart, .* add dagger"):
        BenchmarkConfig(seeds=SEEDS, methods=("bc", "dart"))
    for bad in (-0.1, float("nan"), "0.2", True):
        with pytest.raises(UserError, match="benchmark.dart_noise must be a number >= 0"):
            BenchmarkConfig(seeds=SEEDS, methods=("bc", "dagger", "dart"), dart_noise=bad)


def test_dart_is_a_reference_of_the_paired_comparisons_and_a_curve_of_the_figure(toy_run, rows):
    import json

    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert {"method": "dart", "setting": str(ROUNDS), "demo_fraction": 1.0} in summary["references"]
    assert {"method": "dart", "setting": "1", "demo_fraction": 1.0} not in summary["references"]
    assert any(c["against"] == "dart" and c["method"] == "dagger" for c in summary["comparisons"])
    assert {e["setting"] for e in summary["entries"] if e["method"] == "dart"} == {"1", "2"}
    assert toy_run.benchmark_figure.read_bytes()[:4] == b"\x89PNG"


def test_a_dart_noise_above_one_on_classes_is_refused_naming_the_task():
    config = BenchmarkConfig(seeds=SEEDS, methods=("bc", "dagger", "dart"), dart_noise=1.5)
    config.check_serves(discrete=False, task="fetch")  # a standard deviation on action vectors
    with pytest.raises(UserError, match="dart_noise is 1.5, but carracing acts with classes"):
        config.check_serves(discrete=True, task="carracing")


def test_held_out_expert_states_leave_every_fit_and_measure_every_control_there(toy_run, tmp_path):
    """With ``held_out_every`` k, every k-th demonstration step is neither fitted nor charged, and
    the rows of BC, BC refitted, DAgger and DART carry their head's loss on those expert states,
    BC's as it refits by hand."""
    import shutil

    from metadagger.metal_dagger.controls import expert_loss, held_out
    from metadagger.runfolder.layout import RunLayout

    shutil.copytree(toy_run.root, tmp_path / "run")
    config = dataclasses.replace(CONFIG, methods=(*CONFIG.methods, "bc-refit"), held_out_every=3)
    layout = RunLayout(tmp_path / "run")
    with pytest.raises(UserError, match="held_out_every"):  # the rows made without it are not theirs
        _run(layout, config)
    rows = {(r["method"], r["setting"], r["seed"]): r for r in _run(layout, config, rebuild=True)}
    seed = SEEDS[0]
    with SeedLearner(CorridorTask(), str(toy_run.pistar), seed, head_init_seed=BC.head_init_seed(seed)) as learner:
        kept, held = held_out(demonstration(learner), 3)
        w_bc = bc_head(learner, kept.to_dataset(), seeded(BC, seed))
        assert rows["bc", "", seed]["expert_loss"] == pytest.approx(expert_loss(learner, w_bc, held))
        assert rows["bc", "", seed]["expert_queries"] == kept.steps == len(kept.obs)
    assert len(held) == (kept.steps + len(held)) // 3
    for r in range(1, ROUNDS + 1):
        assert rows["dagger", str(r), seed]["expert_loss"] > 0
        assert rows["dart", str(r), seed]["expert_loss"] > 0
    assert rows["bc-refit", str(ROUNDS), seed]["expert_loss"] > 0
    with pytest.raises(UserError, match="held_out_every must be 0 \\(none\\) or an integer >= 2, got 1"):
        dataclasses.replace(CONFIG, held_out_every=1)
