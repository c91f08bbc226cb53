"""MDM and one-shot evaluation (paper Tables 1-5) on the toy corridor, driven by the per-seed runner."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest
import torch
from toy_mappers import random_conditioned_mapper
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation.mdm import EvalConfig, evaluate_run
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.rollouts import rollout
from metadagger.mapping.mappers import Mapper
from metadagger.metal_dagger.method import seed_context
from metadagger.metal_dagger.pistar import PiStarConfig, head_from_pistar, train_pistar
from metadagger.policies import load_policy
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import load_tensors

GT = PiStarConfig(seeds=(0, 1, 2, 3), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3))
BC = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
SEEDS = (300, 301, 302)


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory) -> RunLayout:
    """pi* of the corridor and two control mappers (pi*'s head, and a zero head that always fails)."""
    layout = RunLayout(tmp_path_factory.mktemp("mdm"))
    train_pistar(CorridorTask(), GT, layout, progress=False)
    head = load_policy(layout.pistar).head_vector()
    Mapper.pistar_head(head).save(layout.mapper("pistar-head"))
    Mapper.mean_da(torch.zeros(2, head.shape[0])).save(layout.mapper("mean-da"))
    return layout


def _copy(layout: RunLayout, to: Path) -> RunLayout:
    shutil.copytree(layout.pistar_dir, to / "pistar")
    shutil.copytree(layout.root / "mappers", to / "mappers")
    return RunLayout(to)


def _evaluate(layout: RunLayout, seeds, methods, lanes: int = 1, **kwargs) -> list[dict]:
    return evaluate_run(
        CorridorTask(),
        layout,
        EvalConfig(seeds=tuple(seeds), methods=tuple(methods), lanes=lanes),
        bc=BC,
        options=StageOptions(**{"workers": 1, "progress": False, **kwargs}),
    )


def test_rows_heads_and_one_shot(toy_run, tmp_path):
    layout = _copy(toy_run, tmp_path)
    rows = _evaluate(layout, SEEDS, ("pistar-head", "mean-da"))
    table = {(r["method"], r["seed"]): r for r in rows}
    demos = {t.seed: t.steps for t in collect(CorridorTask(), SEEDS, policy=None)}
    for seed in SEEDS:
        assert table["pistar-head", seed]["success"]  # pi*'s own head drives the corridor
        assert not table["mean-da", seed]["success"]  # a zero head does not
        # one-shot refits only the failed mapper, on the same demonstration: no new queries
        assert ("oneshot-mean-da", seed) in table and ("oneshot-pistar-head", seed) not in table
        assert {r["expert_queries"] for (m, s), r in table.items() if s == seed} == {demos[seed]}
        for method in ("bc", "pistar-head", "mean-da", "oneshot-mean-da"):
            assert (layout.heads(method) / f"{seed}.safetensors").is_file()
    # the BC row's head is the seed's Xavier head fitted on its demonstration
    policy = head_from_pistar(load_policy(layout.pistar), SEEDS[0])
    fit_bc(
        policy, collect(CorridorTask(), SEEDS[:1], policy=None)[0].to_dataset(), dataclasses.replace(BC, seed=SEEDS[0])
    )
    assert torch.equal(load_tensors(layout.heads("bc") / f"{SEEDS[0]}.safetensors")["head"], policy.head_vector())
    mdm = read_csv(layout.eval_table("mdm"))
    assert [(r["method"], r["seed"]) for r in mdm] == [(m, s) for s in SEEDS for m in ("bc", "pistar-head", "mean-da")]
    assert {r["method"] for r in read_csv(layout.eval_table("oneshot"))} == {"oneshot-mean-da"}


def test_widening_methods_and_seeds_adds_exactly_the_missing_rows(toy_run, tmp_path):
    """A seed evaluated with fewer methods gets exactly the missing rows, never a silent mix."""
    layout = _copy(toy_run, tmp_path)
    _evaluate(layout, SEEDS[:1], ("pistar-head",))
    first = (layout.heads("pistar-head") / f"{SEEDS[0]}.safetensors").stat().st_mtime_ns
    rows = _evaluate(layout, SEEDS[:2], ("pistar-head", "mean-da"))
    assert sorted((r["method"], r["seed"]) for r in rows if not r["method"].startswith("oneshot-")) == sorted(
        (m, s) for s in SEEDS[:2] for m in ("bc", "pistar-head", "mean-da")
    )
    assert (layout.heads("pistar-head") / f"{SEEDS[0]}.safetensors").stat().st_mtime_ns == first  # not redone
    # the same rows as a run that evaluated everything at once
    full = _copy(toy_run, tmp_path / "full")
    _evaluate(full, SEEDS[:2], ("pistar-head", "mean-da"))
    assert layout.eval_table("mdm").read_bytes() == full.eval_table("mdm").read_bytes()


def test_rows_of_a_changed_mapper_are_refused_then_rebuilt(toy_run, tmp_path):
    layout = _copy(toy_run, tmp_path)
    _evaluate(layout, SEEDS[:1], ("pistar-head", "mean-da"))
    head = load_policy(layout.pistar).head_vector()
    Mapper.mean_da(torch.stack([head, head])).save(layout.mapper("mean-da"))
    with pytest.raises(UserError, match="MDM evaluation of 'mean-da' on 1 seed.*mapper: changed.*--rebuild"):
        _evaluate(layout, SEEDS[:1], ("pistar-head", "mean-da"))
    rows = _evaluate(layout, SEEDS[:1], ("pistar-head", "mean-da"), rebuild=True)
    assert next(r for r in rows if r["method"] == "mean-da")["success"]  # now pi*'s head: it succeeds


def test_missing_mapper_is_a_user_error(toy_run, tmp_path):
    layout = _copy(toy_run, tmp_path)
    with pytest.raises(UserError, match="mappers not trained yet: dm"):
        _evaluate(layout, SEEDS[:1], ("dm",))


def test_a_conditioned_mapper_reads_the_seed_context_from_the_bc_rollout(toy_run, tmp_path):
    """Its head is the mapper's output on w_BC and the context of the demonstration and the BC
    head's rollout; its rows give that rollout's env steps and no further expert query."""
    layout = _copy(toy_run, tmp_path)
    pistar = load_policy(layout.pistar)
    mapper = random_conditioned_mapper(pistar, layout.mapper_dir("conditioned"))
    rows = _evaluate(layout, SEEDS, ("conditioned",))
    table = {(r["method"], r["seed"]): r for r in rows}
    for seed in SEEDS:
        policy = head_from_pistar(load_policy(layout.pistar), seed)
        demo = collect(CorridorTask(), [seed], policy=None)[0].to_dataset()
        cache = FeatureCache(policy)
        fit_bc(policy, demo, dataclasses.replace(BC, seed=seed), cache=cache)
        w = policy.head_vector().numpy().copy()
        unlabelled = rollout(CorridorTask().make_env(), seed=seed, policy=policy)
        expected = mapper(w, seed_context(cache, demo.obs, unlabelled.obs))
        assert torch.equal(
            load_tensors(layout.heads("conditioned") / f"{seed}.safetensors")["head"], torch.from_numpy(expected)
        )
        assert table["conditioned", seed]["unlabelled_steps"] == unlabelled.steps == table["bc", seed]["steps"]
        assert table["conditioned", seed]["expert_queries"] == len(demo)
    assert "unlabelled_steps" in read_csv(layout.eval_table("mdm"))[0]


def test_seeds_in_lanes_do_not_depend_on_workers_blocks_or_resume(toy_run, tmp_path):
    """Seeds evaluated in blocks of lanes: the same table and heads with 1 or 3 workers and after a
    run that made part of the seeds; rows made alone are not taken for rows made in lanes."""
    methods = ("pistar-head", "mean-da")
    one, three, resumed = (_copy(toy_run, tmp_path / name) for name in ("one", "three", "resumed"))
    rows = _evaluate(one, SEEDS, methods, lanes=2)  # blocks [300] and [301, 302]
    assert _evaluate(three, SEEDS, methods, lanes=2, workers=3) == rows  # a block of one seed each
    _evaluate(resumed, SEEDS[1:2], methods, lanes=2)
    assert _evaluate(resumed, SEEDS, methods, lanes=2) == rows  # then [300, 302]
    for layout in (three, resumed):
        assert layout.eval_table("mdm").read_bytes() == one.eval_table("mdm").read_bytes()
        for seed in SEEDS:
            name = f"{seed}.safetensors"
            assert (layout.heads("oneshot-mean-da") / name).read_bytes() == (
                one.heads("oneshot-mean-da") / name
            ).read_bytes()
    table = {(r["method"], r["seed"]): r["success"] for r in rows}
    assert all(table["pistar-head", seed] and not table["mean-da", seed] for seed in SEEDS)
    alone = _copy(toy_run, tmp_path / "alone")
    _evaluate(alone, SEEDS, methods)
    with pytest.raises(UserError, match="lanes"):
        _evaluate(alone, SEEDS, methods, lanes=2)
    with pytest.raises(UserError, match="evaluate.lanes must be an integer from 1 to 256, got 0"):
        EvalConfig(lanes=0)
