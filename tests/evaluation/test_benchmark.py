"""Success against expert queries on the toy corridor: exact query counts, every method, resume."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import pytest
import torch
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation.benchmark import figure
from metadagger.evaluation.benchmark import seed_chains as bench
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.methods import GateKey
from metadagger.evaluation.benchmark.protocol import FIELDS, method_keys, run_benchmark
from metadagger.evaluation.report.benchmark import benchmark_section
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.collect import collect
from metadagger.metal_dagger.method import SeedLearner, bc_head, demonstration, seeded
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout

BC = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
SEEDS = (300, 301)
CONFIG = BenchmarkConfig(
    seeds=SEEDS,
    grids={
        "dagger-random": [0.0, 0.5],
        "dagger-ensemble": [0.5],
        "dagger-safe": [0.5],
        "dagger-novelty": [0.5],
        "dagger-thrifty": [0.25],
        "dagger-conformal": [0.5],
        "dagger-oracle": [0.0],
    },
    demo_fractions=(0.5, 1.0),
)
ROUNDS = 2


def _run(
    layout: RunLayout,
    config: BenchmarkConfig = CONFIG,
    *,
    kinds: tuple[str, ...] = ("pistar-head",),
    mdi=None,
    priors: dict | None = None,
    **kwargs,
) -> list[dict]:
    return run_benchmark(
        CorridorTask(),
        layout,
        config,
        rounds=ROUNDS,
        bc=BC,
        dagger_bc=BC,
        early_stop=None,
        kinds=kinds,
        mdi=mdi,
        meta_queries={"pistar": 900, "pairs": 100},
        priors=priors,
        options=StageOptions(**{"workers": 1, "progress": False, **kwargs}),
    )


@pytest.fixture(scope="module")
def rows(toy_run) -> list[dict]:
    return _run(toy_run)


def test_every_method_and_setting_has_a_row_per_seed(toy_run, rows):
    keys = method_keys(CONFIG, rounds=ROUNDS, kinds=("pistar-head",), mdi=False)
    gated = [
        "dagger-random@0",
        "dagger-random@0.5",
        "dagger-ensemble@0.5",
        "dagger-safe@0.5",
        "dagger-novelty@0.5",
        "dagger-thrifty@0.25",
        "dagger-conformal@0.5",
        "dagger-oracle@0",  # the oracle, a reference, last
    ]
    # the shorter demonstration for BC and the gates; pi*'s head never reads it, DAgger keeps the whole one
    assert [key.id for key in keys] == [
        "bc@",
        "bc@@demo0.5",
        "mdm-pistar-head@",
        "dagger@1",
        "dagger@2",
        "bc-refit@2",
        *(k for g in gated for k in (g, g + "@demo0.5")),
    ]
    assert [(r["method"], r["setting"], r["demo_fraction"]) for r in rows] == [
        (key.method, key.setting, key.demo_fraction) for key in keys
    ] * len(SEEDS)
    assert tuple(read_csv(toy_run.benchmark_table)[0]) == FIELDS


def test_queries_are_counted_exactly(toy_run, rows):
    task = CorridorTask()
    demos = {t.seed: t.steps for t in collect(task, SEEDS, policy=None)}
    table = {(r["method"], str(r["setting"]), r["seed"]): r for r in rows if r["demo_fraction"] == 1.0}
    halves = {(r["method"], str(r["setting"]), r["seed"]): r for r in rows if r["demo_fraction"] == 0.5}
    for seed in SEEDS:
        # BC: the demonstration only; a random gate with p = 0 labels nothing more
        for key in (("bc", "", seed), ("dagger-random", "0", seed)):
            assert table[key]["expert_queries"] == demos[seed]
            assert halves[key]["expert_queries"] == math.ceil(demos[seed] / 2)  # its first half only
        # BC refitted as DAgger: the whole demonstration, no label more
        assert table["bc-refit", "2", seed]["expert_queries"] == demos[seed]
        assert ("bc-refit", "2", seed) not in halves
        assert table["mdm-pistar-head", "", seed]["expert_queries"] == 0  # a control asks the expert nothing
        # DAgger labels every state of the rollouts before each refit: BC's, then round 1's policy's
        steps_before = [table["bc", "", seed]["steps"], table["dagger", "1", seed]["steps"]]
        assert table["dagger", "1", seed]["expert_queries"] == demos[seed] + steps_before[0]
        assert table["dagger", "2", seed]["expert_queries"] == demos[seed] + sum(steps_before)
        for method, setting in (
            ("dagger-random", "0.5"),
            ("dagger-ensemble", "0.5"),
            ("dagger-safe", "0.5"),
            ("dagger-novelty", "0.5"),
            ("dagger-thrifty", "0.25"),
            ("dagger-conformal", "0.5"),
        ):
            gated = table[method, setting, seed]["expert_queries"]
            assert demos[seed] <= gated <= table["dagger", "2", seed]["expert_queries"] + 30  # a gate labels a subset
            assert math.ceil(demos[seed] / 2) <= halves[method, setting, seed]["expert_queries"]


def test_each_dagger_row_carries_the_coverage_gap_of_the_states_visited_so_far(toy_run, rows):
    """Plain DAgger's rows hold the gap of every state its rounds visited up to theirs
    (evaluation/benchmark/coverage.py), recomputed here from the seed's demonstration and rollouts; the summary
    reads the last round's."""
    from metadagger.evaluation.benchmark.coverage import coverage_gap

    table = {(r["method"], str(r["setting"]), r["seed"]): r for r in rows if r["demo_fraction"] == 1.0}
    seed = SEEDS[0]
    with SeedLearner(CorridorTask(), str(toy_run.pistar), seed, head_init_seed=BC.head_init_seed(seed)) as learner:
        demo = demonstration(learner)
        first = learner.roll(bc_head(learner, demo.to_dataset(), seeded(BC, seed)))
        features = learner.cache.features_of(demo.to_dataset())
        expected = coverage_gap(features, learner.cache.features_of(first.to_dataset()))
    assert table["dagger", "1", seed]["coverage_gap"] == pytest.approx(expected, abs=1e-9)
    assert all(0.0 <= table["dagger", str(r), s]["coverage_gap"] <= 1.0 for r in (1, 2) for s in SEEDS)
    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert summary["coverage"]["gaps"] == [table["dagger", "2", s]["coverage_gap"] for s in SEEDS]


def test_bc_refit_is_w_bc_refitted_as_dagger_refits_it_on_the_demonstration_alone(toy_run, rows):
    table = {(r["method"], r["seed"]): r for r in rows if r["demo_fraction"] == 1.0}
    for seed in SEEDS:
        with SeedLearner(CorridorTask(), str(toy_run.pistar), seed, head_init_seed=BC.head_init_seed(seed)) as learner:
            data = demonstration(learner).to_dataset()
            head = bc_head(learner, data, seeded(BC, seed))
            assert learner.roll(head).reward == table["bc", seed]["reward"]
            for _ in range(ROUNDS):
                head = bc_head(learner, data, seeded(BC, seed))
            refit = learner.roll(head)
        assert (refit.reward, refit.steps, bool(refit.success)) == (
            table["bc-refit", seed]["reward"],
            table["bc-refit", seed]["steps"],
            table["bc-refit", seed]["success"],
        )


def test_bc_refit_is_a_reference_of_the_paired_comparisons(toy_run, rows):
    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert {"method": "bc-refit", "setting": "2", "demo_fraction": 1.0} in summary["references"]
    assert any(c["against"] == "bc-refit" and c["method"] == "dagger" for c in summary["comparisons"])


def _one_key_job(toy_run, key, seed: int, config: BenchmarkConfig) -> bench.BenchmarkJob:
    """The benchmark job of one method key on one seed of the toy run."""
    return bench.BenchmarkJob(
        task=CorridorTask(),
        pistar=str(toy_run.pistar),
        seed=seed,
        methods=(key.id,),
        keys=(key,),
        mappers={},
        config=config,
        rounds=ROUNDS,
        bc=BC,
        dagger_bc=BC,
        early_stop=None,
        mdi=None,
    )


@pytest.mark.parametrize("gate, value", [("novelty", 0.5), ("thrifty", 0.25), ("conformal", 0.5)])
def test_gated_queries_match_what_the_gates_selected(toy_run, monkeypatch, gate, value):
    """Every query is a state the gate selected: count the selections independently; a gate's memory
    holds the demonstration, then each rollout it has gated, and nothing else; its view's outputs
    are the learner's logits, whose argmax are the classes it took."""
    selected, remembered = [], []
    real = bench.make_gate

    def counting(name, setting, **options):
        gate = real(name, setting, **options)

        class Counting:
            reads_expert = reads_reference = False

            def choose(self, view):
                remembered.append([(len(e.features), e.succeeded) for e in view.memory.episodes])
                # the learner's view: its logits where it acted, their argmax the classes it took
                assert view.discrete and torch.equal(view.outputs.argmax(dim=1), view.actions)
                assert torch.allclose(view.outputs.double(), view.outputs_of(view.head), atol=1e-5)
                chosen = gate.choose(view)
                selected.append(chosen.mask.nonzero().flatten().tolist())
                return chosen

        return Counting()

    monkeypatch.setattr(bench, "make_gate", counting)
    key = GateKey(f"dagger-{gate}", f"{value:g}", gate=gate, value=value)
    job = _one_key_job(toy_run, key, SEEDS[0], CONFIG)
    [row] = bench.benchmark_seed(job)["entries"][key.id]  # in this process: the patch applies
    demo = collect(CorridorTask(), SEEDS[:1], policy=None)[0]
    assert len(selected) == ROUNDS and row["expert_queries"] == demo.steps + sum(map(len, selected))
    # the ledger: the demonstration, then each round's labelled steps exactly, as runs of consecutive steps
    assert [r["round"] for r in row["labels"]] == list(range(ROUNDS + 1))
    assert row["labels"][0]["runs"] == [[0, demo.steps]]
    for record, steps in zip(row["labels"][1:], selected):
        assert [s for a, b in record["runs"] for s in range(a, b)] == steps
        assert all(b2 > a2 > b1 for (_, b1), (a2, b2) in zip(record["runs"], record["runs"][1:]))
    assert row["takeovers"] == sum(len(r["runs"]) for r in row["labels"])
    assert row["episodes_asked"] == 1 + sum(1 for steps in selected if steps)
    bc_row = bench.benchmark_seed(dataclasses.replace(job, methods=("bc@",), keys=(bench.BCKey("bc", ""),)))["entries"][
        "bc@"
    ][0]
    assert remembered == [
        [(demo.steps, demo.success)],
        [(demo.steps, demo.success), (bc_row["steps"], bc_row["success"])],
    ]


def test_a_gates_view_is_one_episodes_states_in_step_order_with_lanes_or_without(toy_run, monkeypatch):
    """Each round hands a gate the states of one rollout, in step order: round 1 the trunk features of
    w_BC's own episode, step by step, and with lanes (several gates' episodes stepped together) the
    same views as without."""
    from metadagger.imitation.lanes import current_lane

    real = bench.make_gate
    seen: dict[str, list[torch.Tensor]] = {}
    in_lane: list[bool] = []

    def recording(name, setting, **options):
        gate = real(name, setting, **options)

        class Recording:
            reads_expert = reads_reference = False

            def choose(self, view):
                seen.setdefault(name, []).append(view.features.clone())
                in_lane.append(current_lane() is not None)
                return gate.choose(view)

        return Recording()

    monkeypatch.setattr(bench, "make_gate", recording)
    keys = tuple(GateKey(f"dagger-{g}", "0.5", gate=g, value=0.5) for g in ("random", "novelty", "safe"))

    def views(lanes: int) -> dict[str, list[torch.Tensor]]:
        seen.clear()
        in_lane.clear()
        job = _one_key_job(toy_run, keys[0], SEEDS[0], dataclasses.replace(CONFIG, lanes=lanes))
        bench.benchmark_seed(dataclasses.replace(job, methods=tuple(k.id for k in keys), keys=keys))
        assert in_lane and all(in_lane) == (lanes > 1) and any(in_lane) == (lanes > 1)
        return dict(seen)

    alone, laned = views(1), views(4)
    seed = SEEDS[0]
    with SeedLearner(CorridorTask(), str(toy_run.pistar), seed, head_init_seed=BC.head_init_seed(seed)) as learner:
        rollout = learner.roll(bc_head(learner, demonstration(learner).to_dataset(), seeded(BC, seed)))
        w_bc_episode = learner.cache.features_of(rollout.to_dataset())
    assert sorted(alone) == sorted(laned) == ["novelty", "random", "safe"]
    for gate in alone:
        assert len(alone[gate]) == len(laned[gate]) == ROUNDS
        assert torch.allclose(alone[gate][0], w_bc_episode, atol=1e-5)
        for by_itself, in_lanes in zip(alone[gate], laned[gate]):
            assert by_itself.shape == in_lanes.shape and torch.allclose(by_itself, in_lanes, atol=1e-5)


def test_resume_and_widening_add_only_the_missing_rows(toy_run, rows, tmp_path):
    layout = RunLayout(tmp_path)
    shutil.copytree(toy_run.pistar_dir, layout.pistar_dir)
    shutil.copytree(toy_run.root / "mappers", layout.root / "mappers")
    _run(layout, dataclasses.replace(CONFIG, seeds=SEEDS[:1], methods=("bc", "dagger")))
    before = layout.benchmark_log.read_text()
    again = _run(layout)
    assert layout.benchmark_log.read_text().startswith(before)
    assert again == rows  # the same rows as one full run
    assert layout.benchmark_table.read_bytes() == toy_run.benchmark_table.read_bytes()


def _copy_run(toy_run, root) -> RunLayout:
    layout = RunLayout(root)
    shutil.copytree(toy_run.pistar_dir, layout.pistar_dir)
    shutil.copytree(toy_run.root / "mappers", layout.root / "mappers")
    return layout


def test_lanes_rows_do_not_depend_on_workers_nor_on_the_methods_beside_them(toy_run, rows, tmp_path):
    """With lanes, every chain of a seed steps in lockstep: the rows are the same with 1 or 2
    workers and for a method run alone; they are the same rows as alone, each recorded with its lanes."""
    laned = dataclasses.replace(CONFIG, lanes=4)
    one = _run(_copy_run(toy_run, tmp_path / "one"), laned)
    two = _run(_copy_run(toy_run, tmp_path / "two"), laned, workers=2)
    assert one == two
    ids = [(r["method"], r["setting"], r["demo_fraction"], r["seed"], r["expert_queries"] > 0) for r in rows]
    assert [(r["method"], r["setting"], r["demo_fraction"], r["seed"], r["expert_queries"] > 0) for r in one] == ids
    key = GateKey("dagger-ensemble", "0.5", gate="ensemble", value=0.5)
    job = _one_key_job(toy_run, key, SEEDS[1], laned)
    [alone] = bench.benchmark_seed(job)["entries"][key.id]
    [beside] = [
        r
        for r in one
        if (r["method"], r["setting"], r["seed"], r["demo_fraction"]) == (key.method, "0.5", SEEDS[1], 1.0)
    ]
    assert {k: alone[k] for k in beside} == beside


def test_the_mdi_rows_run_in_the_seeds_lanes_and_do_not_depend_on_workers(toy_run, tmp_path, monkeypatch):
    """A seed's MDI rows (Table 6's methods) run as one more chain of the seed's lanes, beside the
    first demonstration share's chains: every one-shot and two-shot row is there, as without lanes,
    and the same with 1 or 2 workers."""
    from metadagger.evaluation.mdi import MDIConfig
    from metadagger.imitation.lanes import current_lane

    mdi = MDIConfig(seeds=SEEDS, early_stop=None, mapper="pistar-head", bc=BC, dagger_bc=BC)
    in_lane = []
    evaluate = bench.evaluate_mdi_seed
    monkeypatch.setattr(
        bench, "evaluate_mdi_seed", lambda job: in_lane.append(current_lane() is not None) or evaluate(job)
    )

    def run(name: str, lanes: int, workers: int = 1) -> list[dict]:
        config = dataclasses.replace(CONFIG, methods=("bc", "mdi"), lanes=lanes)
        executor = "inline" if workers == 1 else "local"
        return _run(_copy_run(toy_run, tmp_path / name), config, kinds=(), mdi=mdi, workers=workers, executor=executor)

    alone = run("alone", 1)
    assert in_lane == [False] * len(SEEDS)
    laned = run("laned", 4)
    assert in_lane[len(SEEDS) :] == [True] * len(SEEDS)
    methods, tests = ("dagger-mdi", "dagger-bc-init", "dagger-xavier"), ("one-shot", "two-shot")
    shots = {(r["method"], r["setting"], r["seed"]) for r in laned if r["method"] in methods}
    assert shots == {(m, t, seed) for m in methods for t in tests for seed in SEEDS}
    assert [(r["method"], r["setting"], r["seed"]) for r in alone] == [
        (r["method"], r["setting"], r["seed"]) for r in laned
    ]
    assert run("laned-2", 4, workers=2) == laned


def test_a_laned_seed_reads_the_acting_features_and_fits_its_heads_together(toy_run, monkeypatch):
    """With lanes no image is hashed or passed through the trunk a second time, and every
    head-only fit of the seed runs batched with the others."""
    from metadagger.imitation import lanes as lanes_module
    from metadagger.imitation.features import FeatureCache
    from metadagger.metal_dagger import method

    def no_images(self, images):
        raise AssertionError("an image was hashed for its features")

    def no_single_fit(*args, **kwargs):
        raise AssertionError("a head was fitted alone")

    batches = []

    def counted(fits, **kwargs):
        batches.append(len(fits))
        return fit_heads(fits, **kwargs)

    fit_heads = lanes_module.fit_heads
    monkeypatch.setattr(FeatureCache, "_row_indices", no_images)
    monkeypatch.setattr(method, "fit_bc", no_single_fit)
    monkeypatch.setattr(lanes_module, "fit_heads", counted)
    keys = [key for key in method_keys(CONFIG, rounds=ROUNDS, kinds=(), mdi=False) if key.mapper_kind is None]
    job = dataclasses.replace(
        _one_key_job(toy_run, keys[0], SEEDS[0], dataclasses.replace(CONFIG, lanes=4)),
        methods=tuple(key.id for key in keys),
        keys=tuple(keys),
    )
    entries = bench.benchmark_seed(job)["entries"]
    assert len(entries) == len(keys)
    assert max(batches) > 1  # fits asked for together were run together


def test_rows_made_alone_are_not_reused_for_lanes(toy_run, tmp_path):
    layout = _copy_run(toy_run, tmp_path / "run")
    config = dataclasses.replace(CONFIG, seeds=SEEDS[:1], methods=("bc",))
    _run(layout, config)
    with pytest.raises(UserError, match="lanes"):
        _run(layout, dataclasses.replace(config, lanes=2))
    with pytest.raises(UserError, match="benchmark.lanes must be an integer from 1 to 256, got 0"):
        dataclasses.replace(config, lanes=0)


def _prior_run(layout: RunLayout, priors: dict) -> list[dict]:
    return _run(layout, dataclasses.replace(CONFIG, methods=("bc", "prior"), grids={}), priors=priors)


def test_bc_with_a_prior_spends_the_demonstrations_queries_toward_each_mean(toy_run, tmp_path):
    """``prior`` makes one row per mean (each mapper kind, and zero) and demonstration share, charged
    the share's queries; a prior of strength 0 fits w_BC again (the same rollout as BC); the
    strength and precision are in the rows' stamps, so another prior's rows are never reused."""
    from metadagger.mapping.priors import HeadPrior
    from metadagger.policies import load_policy

    size = load_policy(toy_run.pistar).head_vector().numel()
    priors = {
        "pistar-head": HeadPrior("pistar-head", torch.ones(size), strength=10.0),
        "zero": HeadPrior("zero", torch.ones(size), strength=0.0),
    }
    layout = _copy_run(toy_run, tmp_path / "run")
    rows = _prior_run(layout, priors)
    table = {(r["method"], r["demo_fraction"], r["seed"]): r for r in rows}
    for seed in SEEDS:
        for fraction in (0.5, 1.0):
            bc_row = table["bc", fraction, seed]
            for method in ("prior-pistar-head", "prior-zero"):
                assert table[method, fraction, seed]["expert_queries"] == bc_row["expert_queries"]
            assert table["prior-zero", fraction, seed]["steps"] == bc_row["steps"]
    assert _prior_run(layout, priors) == rows  # resumed: nothing redone
    text = "\n".join(benchmark_section(layout))
    assert "BC, prior toward pi*-head (control)" in text and "BC, prior toward zero" in text
    stronger = {**priors, "pistar-head": dataclasses.replace(priors["pistar-head"], strength=100.0)}
    with pytest.raises(UserError, match="prior"):
        _prior_run(layout, stronger)
    with pytest.raises(
        UserError, match=r"benchmark methods prior, prior-dagger, prior-gated need the priors toward \['zero'\]"
    ):
        _prior_run(layout, {"pistar-head": priors["pistar-head"]})


def test_dagger_with_a_prior_refits_every_round_with_it(toy_run, tmp_path):
    """``prior-dagger`` makes a row per mean and round: round 1 labels every state of BC-with-the-
    prior's rollout (the ``prior`` row's), and a prior of strength 0 pulls nowhere, whatever its mean.
    ``prior-gated`` runs each gated method of the run with the same prior: a random gate that labels
    every state is ``prior-dagger``'s last round, one that labels none BC-with-the-prior's row."""
    from metadagger.mapping.priors import HeadPrior
    from metadagger.policies import load_policy

    size = load_policy(toy_run.pistar).head_vector().numel()
    priors = {mean: HeadPrior(mean, torch.ones(size), strength=0.0) for mean in ("pistar-head", "zero")}
    layout = _copy_run(toy_run, tmp_path / "run")
    config = dataclasses.replace(
        CONFIG,
        methods=("bc", "prior", "prior-dagger", "prior-gated", "dagger-random"),
        grids={"dagger-random": [0.0, 1.0]},
        oracle=False,
        demo_fractions=(1.0,),
    )
    rows = _run(layout, config, priors=priors)
    table = {(r["method"], r["setting"], r["seed"]): r for r in rows}
    for seed in SEEDS:
        demo = table["bc", "", seed]["expert_queries"]
        for mean in ("pistar-head", "zero"):
            first = table[f"prior-dagger-{mean}", "1", seed]
            assert first["expert_queries"] == demo + table[f"prior-{mean}", "", seed]["steps"]
            assert table[f"prior-dagger-{mean}", str(ROUNDS), seed]["expert_queries"] > first["expert_queries"]
        for r in range(1, ROUNDS + 1):
            zero, pistar = table["prior-dagger-zero", str(r), seed], table["prior-dagger-pistar-head", str(r), seed]
            assert {k: v for k, v in zero.items() if k != "method"} == {
                k: v for k, v in pistar.items() if k != "method"
            }
    outcome = ("success", "reward", "steps", "expert_queries", "takeovers", "episodes_asked")
    for seed in SEEDS:
        for mean in ("pistar-head", "zero"):
            gated = f"dagger-random+prior-{mean}"
            every, none = table[gated, "1", seed], table[gated, "0", seed]
            assert all(every[k] == table[f"prior-dagger-{mean}", str(ROUNDS), seed][k] for k in outcome)
            assert all(none[k] == table[f"prior-{mean}", "", seed][k] for k in outcome)
    text = "\n".join(benchmark_section(layout))
    assert "DAgger, prior toward zero" in text and "DAgger, random gate, prior toward zero" in text


def test_the_disagreement_gate_compares_the_current_head_with_the_kinds_head(toy_run, tmp_path, monkeypatch):
    """``disagree-<kind>`` runs DAgger's rounds from w_BC with the disagreement gate, its reference the
    kind's head for w_BC (pi*'s head here) and its current head the one each round's rollout acted
    with; its queries are the demonstration's and the states it chose (its ledger)."""
    from metadagger.imitation.reading_gates import DisagreementGate
    from metadagger.policies import load_policy

    pistar = load_policy(toy_run.pistar).head_vector()
    seen = []
    choose = DisagreementGate.choose

    def spy(self, view):
        seen.append(view)
        return choose(self, view)

    monkeypatch.setattr(DisagreementGate, "choose", spy)
    layout = _copy_run(toy_run, tmp_path / "run")
    config = dataclasses.replace(CONFIG, methods=("bc", "disagree"), grids={}, demo_fractions=(1.0,))
    rows = _run(layout, config, executor="inline", workers=None)  # in this process: the spy sees every choice
    assert len(seen) == len(SEEDS) * 3 * ROUNDS  # every seed, quantile and round
    assert all(torch.equal(h.reference, pistar) for h in seen)
    assert any(not torch.equal(h.head, h.reference) for h in seen)
    table = {(r["method"], r["setting"], r["seed"]): r for r in rows}
    for seed in SEEDS:
        demo = table["bc", "", seed]["expert_queries"]
        for q in ("0.5", "0.8", "0.95"):
            row = table["disagree-pistar-head", q, seed]
            asked = sum(
                stop - start for record in row["labels"] if record["round"] > 0 for start, stop in record["runs"]
            )
            assert row["expert_queries"] == demo + asked
    assert "DAgger, gate: disagreement with pi*-head (control)" in "\n".join(benchmark_section(layout))


def test_every_round_of_dagger_refits_with_the_prior_it_is_given(toy_run):
    """A strong prior pulls every round's refitted head toward its mean (Adam moves a weight by about
    the learning rate a step: a pull, not a jump); a gate that compares heads without a reference
    head is refused."""
    from metadagger.imitation.head_fits import Prior
    from metadagger.imitation.reading_gates import DisagreementGate
    from metadagger.metal_dagger.method import dagger_rounds

    with SeedLearner(CorridorTask(), str(toy_run.pistar), SEEDS[0], head_init_seed=SEEDS[0]) as learner:
        demo = demonstration(learner)
        w_bc = bc_head(learner, demo.to_dataset(), seeded(BC, SEEDS[0]))
        first = learner.roll(w_bc)
        mean = torch.linspace(-1.0, 1.0, len(w_bc))
        prior = Prior(mean=mean, weight=torch.full_like(mean, 1e4))
        heads = [
            r.head
            for r in dagger_rounds(learner, start=w_bc, first_rollout=first, demo=demo, rounds=2, fit=BC, prior=prior)
        ]
        plain = [r.head for r in dagger_rounds(learner, start=w_bc, first_rollout=first, demo=demo, rounds=2, fit=BC)]
        for head, other in zip(heads, plain):
            assert (torch.from_numpy(head) - mean).norm() < (torch.from_numpy(other) - mean).norm() - 0.1
        with pytest.raises(UserError, match="DisagreementGate compares the current head with a reference head"):
            next(
                dagger_rounds(
                    learner, start=w_bc, first_rollout=first, demo=demo, rounds=1, fit=BC, gate=DisagreementGate(0.5)
                )
            )


def test_a_round_that_labels_nothing_rolls_nothing_out_again(toy_run, monkeypatch):
    """A gate that chooses no state leaves the head as it was, so the round's rollout is the last one."""
    from metadagger.imitation.gate_registry import make_gate
    from metadagger.metal_dagger.method import dagger_rounds

    with SeedLearner(CorridorTask(), str(toy_run.pistar), SEEDS[0], head_init_seed=SEEDS[0]) as learner:
        demo = demonstration(learner)
        w_bc = bc_head(learner, demo.to_dataset(), seeded(BC, SEEDS[0]))
        first = learner.roll(w_bc)
        rolled = []
        monkeypatch.setattr(SeedLearner, "roll", lambda self, *a, **k: rolled.append(1))
        rounds = list(
            dagger_rounds(
                learner, start=w_bc, first_rollout=first, demo=demo, rounds=3, fit=BC, gate=make_gate("random", 0.0)
            )
        )
    assert rolled == [] and all(r.rollout is first and r.labelled is None for r in rounds)
    assert [r.queries for r in rounds] == [demo.steps] * 3


def test_summary_figure_and_report_section(toy_run, rows):
    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert summary["meta_training_queries"] == {"pistar": 900, "pairs": 100}
    dagger2 = next(e for e in summary["entries"] if e["method"] == "dagger" and e["setting"] == "2")
    assert (
        dagger2["seeds"] == len(SEEDS)
        and 0 <= dagger2["success_ci_low"] <= dagger2["success_rate"] <= dagger2["success_ci_high"]
    )
    assert toy_run.benchmark_figure.read_bytes()[:4] == b"\x89PNG"
    text = "\n".join(benchmark_section(toy_run))
    assert "## Success against expert queries" in text and "figures/queries.png" in text
    assert "Meta-training spent 1000 expert queries: 900 on pi* and 100 on the pairs." in text
    if dagger2["success_rate"] > 0:
        assert "Cheapest setting reaching 90% of DAgger's final success" in text
    else:  # 90% of nothing: no table that every method would top
        assert "DAgger solves no seed after 2 rounds, so no method can be said to match it." in text
        assert "Cheapest setting" not in text


def test_config_errors():
    with pytest.raises(UserError, match="benchmark.methods has unknown method"):
        BenchmarkConfig(methods=("dagger-magic",))
    # a gate left out of the grids sweeps its declared grid
    assert BenchmarkConfig(grids={"dagger-random": [0.1]}).grid("dagger-ensemble") == [0.5, 0.8, 0.95]
    with pytest.raises(UserError, match="benchmark.gate_options has unknown"):
        BenchmarkConfig(gate_options={"dagger-x": {"k": 1}})
    with pytest.raises(UserError, match="unknown option.* q for gate 'novelty'"):
        BenchmarkConfig(gate_options={"dagger-novelty": {"q": 1}})
    with pytest.raises(UserError, match="benchmark.grids has unknown"):
        BenchmarkConfig(grids={**CONFIG.grids, "dagger-x": [0.5]})
    with pytest.raises(UserError, match="benchmark.methods must not be empty; allowed: bc, mdm, dagger"):
        BenchmarkConfig(methods=())
    with pytest.raises(UserError, match="benchmark.grids.dagger-random is empty"):
        dataclasses.replace(CONFIG, methods=("dagger-random",), grids={"dagger-random": []})


def test_mdi_on_a_run_without_an_mdi_protocol_is_refused_before_any_work(tmp_path):
    layout = RunLayout(tmp_path / "run")
    with pytest.raises(UserError) as info:
        _run(layout, dataclasses.replace(CONFIG, methods=("bc", "mdi")))
    assert str(info.value) == (
        f"benchmark method mdi needs an mdi section, but run {layout.root} has none; "
        "drop mdi from --methods (or benchmark.methods), or add an mdi section"
    )
    assert not layout.root.exists()


def test_matching_table_picks_the_cheapest_setting_that_reaches_dagger(tmp_path):
    from metadagger.utils.io import write_json

    layout = RunLayout(tmp_path)

    def entry(m, s, rate, q):
        return {
            "method": m,
            "setting": s,
            "seeds": 10,
            "successes": int(10 * rate),
            "success_rate": rate,
            "success_ci_low": 0.0,
            "success_ci_high": 1.0,
            "mean_reward": 0.0,
            "mean_queries": q,
        }

    entries = [
        entry("bc", "", 0.1, 100),
        entry("dagger", "1", 0.6, 600),
        entry("dagger", "3", 1.0, 1400),
        entry("dagger-random", "0.05", 0.5, 300),
        entry("dagger-random", "0.5", 0.9, 900),
        entry("dagger-novelty", "0.95", 0.95, 250),
        entry("dagger-novelty", "0.5", 1.0, 700),
        entry("mdm-dm", "", 0.7, 100),
    ]
    write_json(
        layout.benchmark_summary, {"entries": entries, "meta_training_queries": {"pistar": 5000, "pairs": 20000}}
    )
    lines = benchmark_section(layout)
    assert "| DAgger, random gate | 0.5 | 90.0% | 900.0 |" in lines  # 90% of 100%: 0.05 falls short
    assert "| DAgger, novelty gate | 0.95 | 95.0% | 250.0 |" in lines  # the cheaper of two that reach it
    assert "| BC | never | - | - |" in lines and "| DAgger | 3 | 100.0% | 1400.0 |" in lines
    # MDM saves 1300 queries per seed against DAgger's 1400, but succeeds less often: that saving repays nothing
    assert "| MDM DM | 70.0% | 1300.0 | never (success below DAgger's 100.0%) |" in lines


def _entry(method: str, setting: str, rate: float, queries: float, seeds: int = 10) -> dict:
    from metadagger.imitation.metrics import wilson_interval

    low, high = wilson_interval(round(seeds * rate), seeds)
    return {
        "method": method,
        "setting": setting,
        "seeds": seeds,
        "successes": round(seeds * rate),
        "success_rate": rate,
        "success_ci_low": low,
        "success_ci_high": high,
        "mean_reward": 0.0,
        "mean_queries": queries,
    }


def _section(tmp_path, entries: list[dict]) -> list[str]:
    from metadagger.utils.io import write_json

    layout = RunLayout(tmp_path)
    write_json(
        layout.benchmark_summary, {"entries": entries, "meta_training_queries": {"pistar": 5000, "pairs": 20000}}
    )
    return benchmark_section(layout)


def test_only_a_method_that_succeeds_as_often_as_dagger_repays_meta_training(tmp_path):
    lines = _section(
        tmp_path / "a",
        [
            _entry("dagger", "1", 0.5, 600),
            _entry("dagger", "3", 0.8, 1400),
            _entry("mdm-dm", "", 0.8, 100),
            _entry("mdm-ridge", "", 0.9, 150),
            _entry("mdm-sam", "", 0.7, 100),
            _entry("mdm-mean-da", "", 0.0, 100),
            _entry("mdm-tam", "", 1.0, 1500),
        ],
    )
    assert "| MDM DM | 80.0% | 1300.0 | 20 |" in lines  # as often as DAgger: 25000 / 1300 -> 20 seeds
    assert "| MDM Ridge | 90.0% | 1250.0 | 20 |" in lines
    assert "| MDM SAM | 70.0% | 1300.0 | never (success below DAgger's 80.0%) |" in lines
    assert "| MDM mean-DA (control) | 0.0% | 1300.0 | never (success 0%) |" in lines
    assert "| MDM TAM | 100.0% | -100.0 | never (no queries saved) |" in lines
    text = "\n".join(lines)
    assert (
        "Against DAgger after 3 rounds (80.0% success, 1400.0 queries per seed). A method repays meta-training only if "
        "it succeeds, at least as often as DAgger, with fewer queries"
    ) in text
    # DAgger solving nothing: an MDM method solving nothing does not repay anything either
    lines = _section(tmp_path / "b", [_entry("dagger", "1", 0.0, 80), _entry("mdm-dm", "", 0.0, 40)])
    assert "| MDM DM | 0.0% | 40.0 | never (success 0%) |" in lines


def test_a_benchmark_of_gates_alone_has_no_amortised_cost_of_metal_dagger(tmp_path):
    gates = [
        _entry("bc", "", 0.1, 100),
        _entry("dagger", "3", 0.8, 1400),
        _entry("dagger-random", "0.5", 0.6, 700),
        _entry("dagger-novelty", "0.8", 0.7, 400),
    ]
    text = "\n".join(_section(tmp_path / "gates", gates))
    assert "Cheapest setting reaching" in text and "Amortised cost" not in text and "Meta-training" not in text
    # any method that reads the pairs or a mapper brings the section back, even without an MDM row
    for method in ("disagree-ridge", "prior-zero", "dagger-mdi"):
        text = "\n".join(_section(tmp_path / method, [*gates, _entry(method, "", 0.5, 500)]))
        assert "### Amortised cost of MetaL DAgger" in text
        assert "Meta-training spent 25000 expert queries: 5000 on pi* and 20000 on the pairs." in text


def test_query_ticks_and_dodge():
    assert figure.query_ticks([40.0, 41.0, 80.0]) == [40.0, 80.0]  # 41 would print over 40
    # thinned to a ninth of the span apart, then a 1-2-5 sequence only if still too many
    assert figure.query_ticks([10, 15, 23, 35, 52, 80, 120, 180, 270, 400]) == [10, 23, 35, 80, 180, 400]
    assert figure.query_ticks([10 * 10 ** (2 * k / 9) for k in range(10)]) == [10, 20, 50, 100, 200, 500, 1000]
    assert figure.dodge([40.0, 80.0, 40.0], 0.01) == [40.0 * 10**-0.005, 80.0, 40.0 * 10**0.005]


def test_every_wilson_interval_draws(tmp_path):
    from metadagger.imitation.metrics import wilson_interval

    entries = []
    for n in range(1, 201):
        for method, k in (("bc", 0), ("dagger", 1), ("dagger-random", n // 2), ("dagger-safe", n - 1), ("mdm-dm", n)):
            low, high = wilson_interval(k, n)
            entries.append(
                {
                    "method": method,
                    "setting": str(n),
                    "demo_fraction": 1.0,
                    "seeds": n,
                    "successes": k,
                    "success_rate": k / n,
                    "success_ci_low": low,
                    "success_ci_high": high,
                    "mean_reward": 0.0,
                    "mean_queries": float(n),
                }
            )
    path = figure.plot_queries({"entries": entries, "meta_training_queries": {}}, tmp_path / "queries.png")
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_a_failing_figure_keeps_the_rows_and_the_summary(toy_run, rows, tmp_path, capsys, monkeypatch):
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(toy_run.root, layout.root)
    for path in (layout.benchmark_table, layout.benchmark_summary, layout.benchmark_figure):
        path.unlink()
    from metadagger.evaluation.benchmark import protocol as benchmark

    monkeypatch.setattr(benchmark, "plot_queries", lambda summary, path: 1 / 0)
    assert _run(layout) == rows  # every row from the log: nothing run again
    assert layout.benchmark_table.read_bytes() == toy_run.benchmark_table.read_bytes()
    assert layout.benchmark_summary.read_bytes() == toy_run.benchmark_summary.read_bytes()
    assert not layout.benchmark_figure.exists()
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"warning: figure {layout.benchmark_figure} was not drawn (ZeroDivisionError: division by zero)"
    )


def test_a_failing_figure_is_a_line_in_the_report_section(tmp_path, monkeypatch):
    from metadagger.evaluation.report import benchmark as report_benchmark

    monkeypatch.setattr(report_benchmark, "plot_queries", lambda summary, path: 1 / 0)
    lines = _section(tmp_path, [_entry("dagger", "1", 0.5, 600), _entry("mdm-dm", "", 0.5, 100)])
    assert "Figure `queries.png` could not be drawn (ZeroDivisionError: division by zero)." in lines
    assert "| MDM DM | 50.0% | 500.0 | 50 |" in lines


def test_shorter_demonstrations_are_named(toy_run, rows):
    summary = json.loads(toy_run.benchmark_summary.read_text())
    text = "\n".join(benchmark_section(toy_run))
    assert (
        "| BC | 50% of the demonstration |" in text
        and "| DAgger, random gate | 0.5, 50% of the demonstration |" in text
    )
    half = next(e for e in summary["entries"] if e["method"] == "bc" and e["demo_fraction"] == 0.5)
    assert half["seeds"] == len(SEEDS)


def test_demo_fractions_are_checked():
    for bad in ((0.5,), (0.0, 1.0), (0.5, 0.5, 1.0), (1.5, 1.0)):
        with pytest.raises(
            UserError, match=r"benchmark.demo_fractions must be distinct shares in \(0, 1\] with 1 among them"
        ):
            dataclasses.replace(CONFIG, demo_fractions=bad)


def test_a_demonstration_share_is_its_first_steps():
    from metadagger.metal_dagger.method import demonstration_share

    [demo] = collect(CorridorTask(), SEEDS[:1], policy=None)
    assert demonstration_share(demo, 1.0) is demo
    assert demonstration_share(demo, 0.999) is demo  # ceil(0.999 T) = T steps: the whole of it
    for fraction in (0.01, 0.25, 0.5, 0.9):
        part = demonstration_share(demo, fraction)
        n = max(1, math.ceil(fraction * demo.steps))
        assert part.steps == part.expert_queries == len(part.obs) == len(part.expert_labels) == n
        assert (
            (part.obs == demo.obs[:n]).all() and (part.final_obs == demo.obs[n]).all() and part.success == demo.success
        )
        assert part.reward == pytest.approx(float(demo.step_rewards[:n].sum()))
    with pytest.raises(ValueError, match="a demonstration share must be in"):
        demonstration_share(demo, 0.0)


def test_a_method_added_as_docs_benchmark_md_says_runs_beside_the_others(toy_run, tmp_path, monkeypatch):
    """'Adding a method': a BenchmarkMethod with its keys in evaluation/benchmark/methods.py, its chain in
    evaluation/benchmark/seed_chains.py's CHAINS; here the expert's own demonstration as a row."""
    from metadagger.evaluation.benchmark import methods

    @dataclasses.dataclass(frozen=True)
    class ExpertKey(methods.MethodKey):
        pass

    def expert_keys(rounds, kinds, grids, mdi):
        return [ExpertKey("expert", "")]

    def expert_row(job, start, keys, learner):
        return {key: bench.benchmark_row(key, job.seed, start.demo, start.queries, start.labels()) for key in keys}

    declared = methods.BenchmarkMethod("expert", "the expert", "the demonstration itself", expert_keys)
    monkeypatch.setattr(methods, "_BUILT_IN", (*methods._BUILT_IN, declared))
    monkeypatch.setitem(bench.CHAINS, ExpertKey, expert_row)
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(toy_run.root, layout.root)
    config = dataclasses.replace(CONFIG, methods=("bc", "expert"), oracle=False, demo_fractions=(1.0,))
    rows = _run(layout, config, executor="inline")  # a method added in this process: the workers would not know it
    expert = [r for r in rows if r["method"] == "expert"]
    demos = collect(CorridorTask(), SEEDS, policy=None)
    assert [(r["seed"], r["expert_queries"], r["success"]) for r in expert] == [
        (seed, demo.steps, demo.success) for seed, demo in zip(SEEDS, demos)
    ]
    assert all(r["takeovers"] == r["episodes_asked"] == 1 for r in expert)
    from metadagger.evaluation.benchmark.labels import method_label

    assert method_label("expert") == "the expert"
