"""Success against expert queries on the toy corridor: exact query counts, every method, resume."""

from __future__ import annotations

import dataclasses
import json
import shutil

import pytest
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation import benchmark as bench
from metadagger.evaluation.benchmark import BenchmarkConfig, method_keys, run_benchmark
from metadagger.evaluation.methods import GateKey
from metadagger.evaluation.report_benchmark import benchmark_section
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.rollouts import collect
from metadagger.mapping.mappers import Mapper
from metadagger.metal.groundtruth import GroundTruthConfig, train_groundtruth
from metadagger.policies import load_policy
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout

GT = GroundTruthConfig(seeds=(0, 1, 2, 3), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=3))
BC = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
SEEDS = (300, 301)
CONFIG = BenchmarkConfig(seeds=SEEDS, grids={"dagger-random": [0.0, 0.5], "dagger-ensemble": [0.5], "dagger-safe": [0.5],
                                             "dagger-novelty": [0.5]})
ROUNDS = 2


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory) -> RunLayout:
    layout = RunLayout(tmp_path_factory.mktemp("bench"))
    train_groundtruth(CorridorTask(), GT, layout, progress=False)
    Mapper.pistar_head(load_policy(layout.groundtruth).head_vector()).save(layout.mapper("pistar-head"))
    return layout


def _run(layout: RunLayout, config: BenchmarkConfig = CONFIG, **kwargs) -> list[dict]:
    return run_benchmark(CorridorTask(), layout, config, rounds=ROUNDS, bc=BC, dagger_bc=BC, early_stop=None,
                         kinds=("pistar-head",), mdi=None, meta_queries={"pistar": 900, "pairs": 100},
                         options=StageOptions(workers=1, progress=False, **kwargs))


@pytest.fixture(scope="module")
def rows(toy_run) -> list[dict]:
    return _run(toy_run)


def test_every_method_and_setting_has_a_row_per_seed(toy_run, rows):
    keys = method_keys(CONFIG, rounds=ROUNDS, kinds=("pistar-head",), mdi=False)
    assert [key.id for key in keys] == ["bc@", "mdm-pistar-head@", "dagger@1", "dagger@2", "dagger-random@0", "dagger-random@0.5",
                    "dagger-ensemble@0.5", "dagger-safe@0.5", "dagger-novelty@0.5"]
    assert [(r['method'], r['setting']) for r in rows] == [(key.method, key.setting) for key in keys] * len(SEEDS)
    assert tuple(read_csv(toy_run.benchmark_table)[0]) == bench.FIELDS


def test_queries_are_counted_exactly(toy_run, rows):
    task = CorridorTask()
    demos = {t.seed: t.steps for t in collect(task, SEEDS, policy=None)}
    table = {(r["method"], str(r["setting"]), r["seed"]): r for r in rows}
    for seed in SEEDS:
        # BC and MDM: the demonstration only; a random gate with p = 0 labels nothing more
        for key in (("bc", "", seed), ("mdm-pistar-head", "", seed), ("dagger-random", "0", seed)):
            assert table[key]["expert_queries"] == demos[seed]
        # DAgger labels every state of the rollouts before each refit: BC's, then round 1's policy's
        steps_before = [table["bc", "", seed]["steps"], table["dagger", "1", seed]["steps"]]
        assert table["dagger", "1", seed]["expert_queries"] == demos[seed] + steps_before[0]
        assert table["dagger", "2", seed]["expert_queries"] == demos[seed] + sum(steps_before)
        for method in ("dagger-random", "dagger-ensemble", "dagger-safe", "dagger-novelty"):
            gated = table[method, "0.5", seed]["expert_queries"]
            assert demos[seed] <= gated <= table["dagger", "2", seed]["expert_queries"] + 30  # a gate labels a subset


def test_gated_queries_match_what_the_gates_selected(toy_run, monkeypatch):
    """Every query is a state the gate selected: count the selections independently."""
    selected = []
    real = bench.make_gate

    def counting(name, setting, **options):
        gate = real(name, setting, **options)

        class Counting:
            def select(self, *args, **kwargs):
                mask = gate.select(*args, **kwargs)
                selected.append(int(mask.sum()))
                return mask
        return Counting()

    monkeypatch.setattr(bench, "make_gate", counting)
    key = GateKey("dagger-novelty", "0.5", gate="novelty", value=0.5)
    job = bench.BenchmarkJob(task=CorridorTask(), groundtruth=str(toy_run.groundtruth), seed=SEEDS[0],
                             methods=(key.id,), keys=(key,), mappers={}, config=CONFIG, rounds=ROUNDS, bc=BC,
                             dagger_bc=BC, early_stop=None, mdi=None)
    [row] = bench.benchmark_seed(job)["entries"][key.id]  # in this process: the patch applies
    demo = collect(CorridorTask(), SEEDS[:1], policy=None)[0].steps
    assert len(selected) == ROUNDS and row["expert_queries"] == demo + sum(selected)


def test_resume_and_widening_add_only_the_missing_rows(toy_run, rows, tmp_path):
    layout = RunLayout(tmp_path)
    shutil.copytree(toy_run.groundtruth_dir, layout.groundtruth_dir)
    shutil.copytree(toy_run.root / "mappers", layout.root / "mappers")
    _run(layout, dataclasses.replace(CONFIG, seeds=SEEDS[:1], methods=("bc", "dagger")))
    before = layout.benchmark_log.read_text()
    again = _run(layout)
    assert layout.benchmark_log.read_text().startswith(before)
    assert again == rows  # the same rows as one full run
    assert layout.benchmark_table.read_bytes() == toy_run.benchmark_table.read_bytes()


def test_summary_figure_and_report_section(toy_run, rows):
    summary = json.loads(toy_run.benchmark_summary.read_text())
    assert summary["meta_training_queries"] == {"pistar": 900, "pairs": 100}
    dagger2 = next(e for e in summary["entries"] if e["method"] == "dagger" and e["setting"] == "2")
    assert dagger2["seeds"] == len(SEEDS) and 0 <= dagger2["success_ci_low"] <= dagger2["success_rate"] <= dagger2["success_ci_high"]
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
    with pytest.raises(UserError, match="benchmark.grids.dagger-ensemble is missing"):
        BenchmarkConfig(grids={"dagger-random": [0.1]})
    with pytest.raises(UserError, match="benchmark.grids has unknown"):
        BenchmarkConfig(grids={**CONFIG.grids, "dagger-x": [0.5]})
    with pytest.raises(UserError, match="benchmark.methods must not be empty; allowed: bc, mdm, dagger"):
        BenchmarkConfig(methods=())
    with pytest.raises(UserError, match="benchmark.grids.dagger-random is missing or empty"):
        dataclasses.replace(CONFIG, methods=("dagger-random",), grids={"dagger-random": []})


def test_mdi_on_a_run_without_an_mdi_protocol_is_refused_before_any_work(tmp_path):
    layout = RunLayout(tmp_path / "run")
    with pytest.raises(UserError) as info:
        _run(layout, dataclasses.replace(CONFIG, methods=("bc", "mdi")))
    assert str(info.value) == (f"benchmark method mdi needs an mdi section, but run {layout.root} has none; "
                               "drop mdi from --methods (or benchmark.methods), or add an mdi section")
    assert not layout.root.exists()


def test_matching_table_picks_the_cheapest_setting_that_reaches_dagger(tmp_path):
    from metadagger.utils.io import write_json

    layout = RunLayout(tmp_path)
    entry = lambda m, s, rate, q: {"method": m, "setting": s, "seeds": 10, "successes": int(10 * rate), "success_rate": rate,  # noqa: E731
                                   "success_ci_low": 0.0, "success_ci_high": 1.0, "mean_reward": 0.0, "mean_queries": q}
    entries = [entry("bc", "", 0.1, 100), entry("dagger", "1", 0.6, 600), entry("dagger", "3", 1.0, 1400),
               entry("dagger-random", "0.05", 0.5, 300), entry("dagger-random", "0.5", 0.9, 900),
               entry("dagger-novelty", "0.95", 0.95, 250), entry("dagger-novelty", "0.5", 1.0, 700), entry("mdm-dm", "", 0.7, 100)]
    write_json(layout.benchmark_summary, {"entries": entries, "meta_training_queries": {"pistar": 5000, "pairs": 20000}})
    lines = benchmark_section(layout)
    assert "| DAgger, random gate | 0.5 | 90.0% | 900.0 |" in lines  # 90% of 100%: 0.05 falls short
    assert "| DAgger, novelty gate | 0.95 | 95.0% | 250.0 |" in lines  # the cheaper of two that reach it
    assert "| BC | never | - | - |" in lines and "| DAgger | 3 | 100.0% | 1400.0 |" in lines
    # MDM saves 1300 queries per seed against DAgger's 1400: 25000 / 1300 -> 20 seeds
    assert "| MDM DM | 70.0% | 1300.0 | 20 |" in lines
