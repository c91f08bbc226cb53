"""The MDI protocol (paper Table 6) on the toy corridor's Box variant, and its report section."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest
import torch
from toy_mappers import random_conditioned_mapper
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.methods import MDI_METHODS
from metadagger.evaluation.mdi import MDI_FIELDS, MDIConfig, evaluate_mdi, head_folder
from metadagger.evaluation.report.mdi import FIGURE, mdi_section
from metadagger.evaluation.rows import read_csv, write_csv
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.rollouts import rollout
from metadagger.mapping.mappers import Mapper
from metadagger.metal_dagger.method import seed_context
from metadagger.metal_dagger.pistar import PiStarConfig, head_from_pistar, train_pistar
from metadagger.pipeline.run_config import init_run, load_run
from metadagger.policies import load_policy
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import load_tensors

GT = PiStarConfig(seeds=(0, 1, 2, 3), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3))
# 1-D displacements: the cosine distance per step is 0 (same sign), 1 (one is zero) or 2 (opposite)
CONFIG = MDIConfig(
    seeds=(300, 301, 302),
    early_stop=6.0,
    mapper="pistar-head",
    bc=BCConfig(lr=1e-2, batch_size=10, epochs=2, head_only=True),
    dagger_bc=BCConfig(lr=1e-2, batch_size=10, epochs=2, head_only=True),
)


def pistar_path(run: Path) -> Path:
    return RunLayout(run).pistar


def head_dir(run: Path, method: str, shot: str) -> Path:
    return RunLayout(run).heads(head_folder(method, shot))


def copy_run(run: Path, to: Path) -> None:
    """pi* and the mappers of ``run`` in a fresh folder (no evaluation yet)."""
    shutil.copytree(run / "pistar", to / "pistar")
    shutil.copytree(run / "mappers", to / "mappers")


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory) -> tuple[Path, Path]:
    """A run folder with a tiny pi* (Box corridor) and a pi*-head control mapper as the MDI mapper."""
    run = tmp_path_factory.mktemp("mdi")
    train_pistar(CorridorTask(discrete=False), GT, RunLayout(run), progress=False)
    mapper = RunLayout(run).mapper("pistar-head")
    Mapper.pistar_head(load_policy(pistar_path(run)).head_vector()).save(mapper)
    return run, mapper


@pytest.fixture(scope="module")
def evaluated(toy_run) -> tuple[Path, list[dict]]:
    run, mapper = toy_run
    rows = evaluate_mdi(CorridorTask(discrete=False), RunLayout(run), CONFIG, StageOptions(workers=1, progress=False))
    return run, rows


def test_rows_cover_every_method_and_seed_with_all_fields(evaluated):
    run, rows = evaluated
    assert [(r["method"], r["seed"]) for r in rows] == [(m, s) for s in CONFIG.seeds for m in MDI_METHODS]
    assert all(set(r) == set(MDI_FIELDS) for r in rows)
    csv_rows = read_csv(run / "eval" / "mdi.csv")
    assert [(r["method"], r["seed"], r["one_shot_success"]) for r in csv_rows] == [
        (r["method"], r["seed"], r["one_shot_success"]) for r in rows
    ]


def test_two_shot_runs_only_after_a_failed_one_shot(evaluated):
    run, rows = evaluated
    assert {r["two_shot_run"] for r in rows} == {True, False}, "the toy run should exercise both branches"
    for r in rows:
        assert r["two_shot_run"] == (not r["one_shot_success"])
        assert r["two_shot_success"] >= r["one_shot_success"]  # two-shot counts seeds solved at either test
        twoshot = head_dir(run, r["method"], "twoshot") / f"{r['seed']}.safetensors"
        assert twoshot.is_file() == r["two_shot_run"]
        assert (head_dir(run, r["method"], "oneshot") / f"{r['seed']}.safetensors").is_file()
        if not r["two_shot_run"]:
            assert r["two_shot_reward"] is None and r["two_shot_steps"] is None


def test_expert_queries_add_up(evaluated):
    _, rows = evaluated
    demos = {t.seed: t.steps for t in collect(CorridorTask(discrete=False), CONFIG.seeds, policy=None)}
    for r in rows:
        assert r["demo_steps"] == demos[r["seed"]]
        # the DAgger round labels every state of the failed one-shot rollout
        assert r["expert_queries"] == r["demo_steps"] + (r["one_shot_steps"] if r["two_shot_run"] else 0)


def test_cosine_distances_and_early_stop(evaluated):
    _, rows = evaluated
    for r in rows:
        final_steps = r["two_shot_steps"] if r["two_shot_run"] else r["one_shot_steps"]
        assert 0.0 <= r["cosine_total"] <= 2.0 * final_steps
        assert r["cosine_per_action"] == pytest.approx(r["cosine_total"] / final_steps)
        stopped = r["two_shot_early_stopped"] if r["two_shot_run"] else r["one_shot_early_stopped"]
        # the early stop cuts an episode once the accumulated distance passes the threshold
        assert stopped == (r["cosine_total"] > CONFIG.early_stop)
        if stopped:
            assert not r["two_shot_success"]


def test_dagger_one_shot_head_is_a_fresh_bc_fit_on_the_demo(evaluated):
    run, _ = evaluated
    seed = CONFIG.seeds[0]
    policy = head_from_pistar(load_policy(pistar_path(run)), seed)
    demo = collect(CorridorTask(discrete=False), [seed], policy=None)[0].to_dataset()
    fit_bc(policy, demo, dataclasses.replace(CONFIG.bc, seed=seed))
    head = {m: load_tensors(head_dir(run, m, "oneshot") / f"{seed}.safetensors")["head"] for m in MDI_METHODS}
    assert torch.equal(head["dagger-xavier"], policy.head_vector())
    # DAgger-BC refits w_BC once more on the demonstration; DAgger-MDI starts from the mapper's output
    assert not torch.equal(head["dagger-bc-init"], head["dagger-xavier"])
    assert not torch.equal(head["dagger-mdi"], head["dagger-bc-init"])


@pytest.mark.parametrize("dagger_init", ["saved", "one-shot"])
def test_dagger_round_refits_from_the_configured_start(evaluated, dagger_init, tmp_path):
    run, rows = evaluated
    failed = [r for r in rows if r["two_shot_run"]]
    assert {r["method"] for r in failed} >= {"dagger-xavier"}, "the toy run should fail DAgger's one-shot somewhere"
    config = dataclasses.replace(CONFIG, dagger_init=dagger_init)
    if dagger_init == "one-shot":  # evaluate a copy with the other setting
        copy_run(run, tmp_path)
        run = tmp_path
        evaluate_mdi(CorridorTask(discrete=False), RunLayout(run), config, StageOptions(workers=1, progress=False))
    r = next(r for r in failed if r["method"] == "dagger-xavier")
    seed = r["seed"]
    task = CorridorTask(discrete=False)
    policy = head_from_pistar(load_policy(pistar_path(run)), seed)  # the seed's Xavier head
    demo = collect(task, [seed], policy=None)[0].to_dataset()
    oneshot = load_tensors(head_dir(run, "dagger-xavier", "oneshot") / f"{seed}.safetensors")["head"]
    policy.load_head_vector(oneshot)
    first = collect(
        task, [seed], policy=policy, early_stop_factory=lambda: CosineEarlyStop(threshold=CONFIG.early_stop)
    )[0]
    if dagger_init == "saved":  # Table 6 step 8 for DAgger: a Xavier head again
        policy = head_from_pistar(load_policy(pistar_path(run)), seed)
    fit_bc(policy, demo.concat(first.to_dataset()), dataclasses.replace(CONFIG.dagger_bc, seed=seed))
    twoshot = load_tensors(head_dir(run, "dagger-xavier", "twoshot") / f"{seed}.safetensors")["head"]
    assert torch.equal(twoshot, policy.head_vector())


def test_resume_skips_finished_seeds_and_matches_a_full_run(toy_run, evaluated, tmp_path):
    run, mapper = toy_run
    task = CorridorTask(discrete=False)
    copy_run(run, tmp_path)
    first = MDIConfig(**{**CONFIG.__dict__, "seeds": CONFIG.seeds[:1]})
    evaluate_mdi(task, RunLayout(tmp_path), first, StageOptions(workers=1, progress=False))
    head = head_dir(tmp_path, "dagger-xavier", "oneshot") / f"{CONFIG.seeds[0]}.safetensors"
    stamp = head.stat().st_mtime_ns
    evaluate_mdi(task, RunLayout(tmp_path), CONFIG, StageOptions(workers=1, progress=False))
    assert head.stat().st_mtime_ns == stamp
    assert (tmp_path / "eval" / "mdi.csv").read_bytes() == (evaluated[0] / "eval" / "mdi.csv").read_bytes()


def test_report_section_renders_from_the_csv_alone(evaluated, tmp_path):
    (tmp_path / "eval").mkdir()
    shutil.copy(evaluated[0] / "eval" / "mdi.csv", tmp_path / "eval" / "mdi.csv")
    lines = mdi_section(RunLayout(tmp_path))
    text = "\n".join(lines)
    assert "Table 7" in text and all(name in text for name in ("DAgger-MDI", "DAgger-BC", "| DAgger from Xavier |"))
    assert f"figures/{FIGURE}" in text and (tmp_path / "report" / "figures" / FIGURE).is_file()
    assert mdi_section(RunLayout(tmp_path / "missing")) == []


def test_discrete_task_has_no_cosine_distances_and_no_figure(tmp_path):
    task = CorridorTask(discrete=True)
    train_pistar(
        task,
        PiStarConfig(**{**GT.__dict__, "seeds": (0, 1), "dagger_rounds": 0}),
        RunLayout(tmp_path),
        progress=False,
    )
    mapper = RunLayout(tmp_path).mapper("pistar-head")
    Mapper.pistar_head(load_policy(pistar_path(tmp_path)).head_vector()).save(mapper)
    config = MDIConfig(**{**CONFIG.__dict__, "seeds": (300,), "early_stop": None})
    rows = evaluate_mdi(task, RunLayout(tmp_path), config, StageOptions(workers=1, progress=False))
    assert len(rows) == len(MDI_METHODS)
    assert all(r["cosine_total"] is None and r["cosine_per_action"] is None for r in rows)
    assert not any(r["one_shot_early_stopped"] for r in rows)
    lines = mdi_section(RunLayout(tmp_path))
    assert any("Table 7" in line for line in lines) and not (tmp_path / "report" / "figures" / FIGURE).exists()


def test_table7_counts_and_wilson_intervals(tmp_path):
    rows = []
    for seed, (one, two) in enumerate([(True, True), (False, True), (False, False), (False, False)]):
        for method in MDI_METHODS:
            rows.append(
                {
                    "method": method,
                    "seed": seed,
                    "one_shot_success": one,
                    "two_shot_success": two,
                    "two_shot_run": not one,
                    "expert_queries": 50 + (0 if one else 20),
                    "cosine_total": None,
                    "cosine_per_action": None,
                }
            )
    write_csv(tmp_path / "eval" / "mdi.csv", rows, fields=MDI_FIELDS)
    lines = mdi_section(RunLayout(tmp_path))
    # 1/4 -> Wilson 4.6%-69.9%, 2/4 -> 15.0%-85.0%; queries (50 + 3 * 70) / 4 = 65
    assert "| DAgger-MDI | 25.0% (1/4; 4.6%-69.9%) | 50.0% (2/4; 15.0%-85.0%) | 65.0 |" in lines
    assert not any("Fig. 5" in line for line in lines)  # no distances recorded: no figure
    assert not (RunLayout(tmp_path).figures / FIGURE).exists()


def test_fig5_counts_the_seeds_where_dagger_mdi_is_closer(tmp_path):
    totals = {"dagger-mdi": [1.0, 5.0, 2.0], "dagger-bc-init": [3.0, 4.0, 6.0], "dagger-xavier": [0.5, 9.0, 2.0]}
    rows = [
        {
            "method": m,
            "seed": seed,
            "one_shot_success": False,
            "two_shot_success": False,
            "expert_queries": 60,
            "cosine_total": totals[m][seed],
            "cosine_per_action": totals[m][seed] / 10,
        }
        for seed in range(3)
        for m in MDI_METHODS
    ]
    write_csv(tmp_path / "eval" / "mdi.csv", rows, fields=MDI_FIELDS)
    lines = mdi_section(RunLayout(tmp_path))
    assert "| DAgger-BC | 3 | 2/3 | 2/3 |" in lines
    assert "| DAgger from Xavier | 3 | 1/3 | 1/3 |" in lines  # a tie is not "lower"
    assert (RunLayout(tmp_path).figures / FIGURE).is_file()


def test_controls_add_rows_and_rerun_seeds_logged_without_them(toy_run, evaluated, tmp_path):
    run, mapper = toy_run
    task = CorridorTask(discrete=False)
    copy_run(run, tmp_path)
    evaluate_mdi(task, RunLayout(tmp_path), CONFIG, StageOptions(workers=1, progress=False))
    head = load_policy(pistar_path(run)).head_vector()
    control = RunLayout(tmp_path).mapper("mean-da")
    Mapper.mean_da(torch.stack([head, head])).save(control)  # the mean is pi*'s head, the MDI mapper's output
    config = dataclasses.replace(CONFIG, controls=("mean-da",))
    assert config.methods == MDI_METHODS + ("dagger-mdi-mean-da",)
    rows = evaluate_mdi(task, RunLayout(tmp_path), config, StageOptions(workers=1, progress=False))
    assert [(r["method"], r["seed"]) for r in rows] == [(m, s) for s in CONFIG.seeds for m in config.methods]
    # the three methods' rows do not change; a mean-DA head equal to pi*'s head gives DAgger-MDI's rows
    main = {(r["method"], r["seed"]): r for r in evaluated[1]}
    for r in rows:
        expected = main[("dagger-mdi" if r["method"] == "dagger-mdi-mean-da" else r["method"], r["seed"])]
        assert {k: v for k, v in r.items() if k != "method"} == {k: v for k, v in expected.items() if k != "method"}
    assert (head_dir(tmp_path, "dagger-mdi-mean-da", "oneshot") / f"{CONFIG.seeds[0]}.safetensors").is_file()
    text = "\n".join(mdi_section(RunLayout(tmp_path)))
    assert "| control: DAgger-MDI initialised by mean-da |" in text


def test_missing_inputs_are_user_errors(toy_run, tmp_path):
    run, mapper = toy_run
    task = CorridorTask(discrete=False)
    shutil.copytree(run / "pistar", tmp_path / "pistar")
    with pytest.raises(UserError, match="train-mapper"):  # no mapper in this run
        evaluate_mdi(task, RunLayout(tmp_path), CONFIG, StageOptions(progress=False))
    with pytest.raises(UserError, match="early_stop"):
        evaluate_mdi(CorridorTask(discrete=True), RunLayout(run), CONFIG, StageOptions(progress=False))
    Mapper.pistar_head(torch.zeros(7)).save(RunLayout(tmp_path).mapper("pistar-head"))
    with pytest.raises(UserError, match="length 7"):
        evaluate_mdi(task, RunLayout(tmp_path), CONFIG, StageOptions(progress=False))


def test_rows_of_a_changed_mapper_are_refused_then_rebuilt(toy_run, evaluated, tmp_path):
    run, _ = toy_run
    copy_run(run, tmp_path)
    layout = RunLayout(tmp_path)
    task = CorridorTask(discrete=False)
    evaluate_mdi(task, layout, CONFIG, StageOptions(workers=1, progress=False))
    Mapper.pistar_head(torch.zeros_like(load_policy(layout.pistar).head_vector())).save(layout.mapper("pistar-head"))
    with pytest.raises(UserError, match="'dagger-mdi'.*mapper: changed.*--rebuild"):
        evaluate_mdi(task, layout, CONFIG, StageOptions(workers=1, progress=False))
    before = {(r["method"], r["seed"]): r for r in read_csv(layout.eval_table("mdi"))}
    rows = evaluate_mdi(task, layout, CONFIG, StageOptions(rebuild=True, workers=1, progress=False))
    # only DAgger-MDI's rows depend on the mapper: the others are reused as they were
    for r in rows:
        if r["method"] != "dagger-mdi":
            assert r["one_shot_reward"] == before[(r["method"], r["seed"])]["one_shot_reward"]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seeds": ()}, "mdi.seeds must not be empty"),
        ({"controls": ("dm",)}, "mdi.controls must be distinct mapper kinds"),
        ({"dagger_init": "xavier"}, "mdi.dagger_init must be one of saved, one-shot"),
        ({"controls": ("mean-da", "mean-da")}, "mdi.controls must be distinct"),
        ({"controls": ("nope",)}, "got \\['nope'\\]"),
        ({"seeds": (-1,)}, "non-negative"),
        ({"bc": BCConfig(head_only=False)}, "head_only"),
        ({"bc": None, "dagger_bc": BCConfig(head_only=False)}, "head_only"),
        ({"early_stop": 0.0}, "mdi.early_stop"),
        ({"early_stop": float("inf")}, "mdi.early_stop"),
        ({"mapper": "xyz"}, "mdi.mapper"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(UserError, match=match):
        MDIConfig(**kwargs)


@pytest.mark.parametrize("preset", ["quick", "paper", "ci"])
def test_fetch_presets_build(preset, tmp_path):
    config = init_run(tmp_path, "fetch", preset)  # RunConfig rejects MDI seeds used for pi* or the pairs
    assert load_run(tmp_path) == config  # the mdi section survives config.yaml
    mdi = config.mdi
    assert mdi is not None and mdi.early_stop is not None
    assert mdi.mapper in config.mappers and mdi.mapper in config.mapper_kinds  # configured, and trained by reproduce
    assert config.mapper_config(mdi.mapper).kind == mdi.mapper
    assert mdi.bc is None and config.mdi_config.bc == config.pairs.bc  # MDI's BC fit is the pairs' BC fit


def test_an_mdi_bc_other_than_the_pairs_is_refused(tmp_path):
    with pytest.raises(UserError, match="mdi.bc differs from pairs.bc"):
        init_run(tmp_path, "fetch", "ci", overrides=["mdi.bc={lr: 0.5, head_only: true}"])


def test_a_conditioned_initialiser_reads_the_seed_context(toy_run, tmp_path):
    """Its step-4 initialisation is the mapper's output on w_BC and the context of the
    demonstration and the BC head's rollout under the pairs' early stop."""
    run, _ = toy_run
    copy_run(run, tmp_path)
    layout = RunLayout(tmp_path)
    pistar = load_policy(layout.pistar)
    mapper = random_conditioned_mapper(pistar, layout.mapper_dir("conditioned"))
    config = dataclasses.replace(CONFIG, controls=("conditioned",))
    evaluate_mdi(
        CorridorTask(discrete=False), layout, config, StageOptions(workers=1, progress=False), context_early_stop=3.0
    )
    seed = CONFIG.seeds[0]
    policy = head_from_pistar(pistar, CONFIG.bc.head_init_seed(seed))
    demo = collect(CorridorTask(discrete=False), [seed], policy=None)[0].to_dataset()
    cache, bc = FeatureCache(policy), dataclasses.replace(CONFIG.bc, seed=seed)
    fit_bc(policy, demo, bc, cache=cache)
    unlabelled = rollout(
        CorridorTask(discrete=False).make_env(), seed=seed, policy=policy, early_stop=CosineEarlyStop(threshold=3.0)
    )
    policy.load_head_vector(
        torch.from_numpy(mapper(policy.head_vector().numpy(), seed_context(cache, demo.obs, unlabelled.obs)))
    )
    fit_bc(policy, demo, bc, cache=cache)
    saved = load_tensors(head_dir(tmp_path, "dagger-mdi-conditioned", "oneshot") / f"{seed}.safetensors")["head"]
    assert torch.equal(saved, policy.head_vector())


def test_seeds_in_lanes_do_not_depend_on_workers_blocks_or_resume(toy_run, evaluated, tmp_path):
    run, _ = toy_run
    task = CorridorTask(discrete=False)
    laned = dataclasses.replace(CONFIG, lanes=2)
    tables = []
    for name, steps in (("one", [(laned, 1)]), ("two", [(laned, 2)]), ("resumed", [(laned, 1), (laned, 1)])):
        copy_run(run, tmp_path / name)
        if name == "resumed":
            steps[0] = (dataclasses.replace(laned, seeds=CONFIG.seeds[-1:]), 1)
        for config, workers in steps:
            rows = evaluate_mdi(task, RunLayout(tmp_path / name), config, StageOptions(workers=workers, progress=False))
        tables.append((tmp_path / name / "eval" / "mdi.csv").read_bytes())
    assert tables[0] == tables[1] == tables[2]
    # the same protocol: every method and seed has its row, and two shots only after a failed one
    assert [(r["method"], r["seed"]) for r in rows] == [(r["method"], r["seed"]) for r in evaluated[1]]
    assert all(r["two_shot_run"] == (not r["one_shot_success"]) for r in rows)
    with pytest.raises(UserError, match="lanes"):  # rows made alone are not taken for rows made in lanes
        evaluate_mdi(task, RunLayout(evaluated[0]), laned, StageOptions(workers=1, progress=False))
    with pytest.raises(UserError, match="mdi.lanes must be an integer from 1 to 256, got 0"):
        dataclasses.replace(CONFIG, lanes=0)
