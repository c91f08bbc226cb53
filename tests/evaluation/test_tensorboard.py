"""TensorBoard scalars of a tiny corridor run, read back from the event files: every namespace's
tags and values equal the run's artifacts, a re-run replaces instead of adding points, off by
default, and a missing tensorboard is one clear line."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from toy_task import TINY_PRESETS, RunCorridorTask
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.evaluation.rows import CURVE_COLUMNS, read_csv
from metadagger.evaluation.tensorboard import INSTALL, benchmark_scalars, pistar_scalars, require_tensorboard
from metadagger.metal_dagger.store import PairStore
from metadagger.runfolder.layout import RunLayout

runner = CliRunner()
TASK = "corridor-tb"
NAMESPACES = ("benchmark", "eval/mdi", "eval/mdm", "pistar", "mapper/dm", "mapper/sam", "pairs")
# the tiny preset with a SAM (an autoencoder, then h), an mdi and a benchmark section, all cut short
OVERRIDES = (
    "evaluate.methods=[dm, sam]",
    "mappers={dm: {epochs: 4}, sam: {epochs: 3, ae_epochs: 2}}",
    "mdi={seeds: [500], dagger_bc: {lr: 0.01, batch_size: 10, epochs: 1, head_only: true}}",
    "benchmark={seeds: [400], methods: [bc, mdm, dagger, dagger-random], grids: {dagger-random: [0.5]}}",
)


def _reproduce(run: Path, presets: Path, *args: str) -> str:
    sets = [arg for item in OVERRIDES for arg in ("--set", item)]
    result = runner.invoke(
        app,
        [
            "reproduce",
            "--task",
            TASK,
            "--presets",
            str(presets),
            "--preset",
            "tiny",
            "--out",
            str(run),
            "--workers",
            "1",
            *sets,
            *args,
        ],
    )
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def presets(tmp_path_factory):
    """The tiny presets file, with the corridor registered as a task for the module's runs."""
    from metadagger.tasks import _FACTORIES, register_task

    path = tmp_path_factory.mktemp("presets") / "presets.yaml"
    path.write_text(TINY_PRESETS)
    register_task(TASK, RunCorridorTask)
    yield path
    del _FACTORIES[TASK]


@pytest.fixture(scope="module")
def run(presets, tmp_path_factory) -> RunLayout:
    """A finished tiny run with ``--log tensorboard``."""
    pytest.importorskip("tensorboard")
    root = tmp_path_factory.mktemp("tb") / "run"
    out = _reproduce(root, presets, "--log", "tensorboard")
    assert f"tensorboard --logdir {root / 'tb'}" in out
    return RunLayout(root)


def _read(layout: RunLayout, namespace: str) -> dict[str, list[tuple[int, float]]]:
    """Every scalar of one namespace: tag -> [(step, value)]."""
    from tensorboard.backend.event_processing.event_accumulator import SCALARS, EventAccumulator

    events = EventAccumulator(str(layout.tb_run(namespace)), size_guidance={SCALARS: 0})
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def _f32(values) -> list[float]:
    """What an event file holds of ``values`` (float32)."""
    return [float(np.float32(v)) for v in values]


def test_every_namespace_is_written_and_every_tag_is_namespaced(run):
    folders = sorted(str(p.parent.relative_to(run.tb_dir)) for p in run.tb_dir.rglob("events.out.tfevents.*"))
    assert folders == sorted(NAMESPACES)  # one event file each
    for namespace in NAMESPACES:
        assert all(tag.startswith(namespace + "/") for tag in _read(run, namespace))


def test_pistar_scalars_equal_its_metrics(run):
    metrics = json.loads(run.pistar_metrics.read_text())
    scalars = _read(run, "pistar")
    fits = [metrics["bc_epoch_losses"]] + [r["dagger/epoch_losses"] for r in metrics["rounds"]]
    epochs = len(fits[0])
    assert epochs == 1 and len(fits) == 2  # the tiny preset: one epoch per fit, one DAgger round
    assert scalars["pistar/loss"] == list(zip(range(1, 1 + epochs * len(fits)), _f32(sum(fits, []))))
    assert metrics["rounds"][0]["dagger/final_loss"] == fits[1][-1]
    assert scalars["pistar/dagger/expert_queries"] == [(1, metrics["rounds"][0]["dagger/expert_queries"])]
    assert scalars["pistar/dagger/mean_reward"] == [(1, *_f32([metrics["rounds"][0]["dagger/mean_reward"]]))]
    for key in ("success_rate", "success_ci_high", "mean_reward"):
        assert scalars[f"pistar/unseen_seeds/{key}"] == [(1, *_f32([metrics["unseen_seeds"][key]]))]


def test_pair_scalars_equal_the_records_and_summary(run):
    records = PairStore(run.pairs_dir).records()
    scalars = _read(run, "pairs")
    for outcome in ("bc", "da"):
        for key in ("success", "reward", "steps", "expert_queries"):
            assert scalars[f"pairs/{outcome}/{key}"] == [(r["seed"], float(r[outcome][key])) for r in records]
    assert scalars["pairs/kept"] == [(r["seed"], float(r["kept"])) for r in records]
    summary = json.loads(run.pairs_summary.read_text())
    assert scalars["pairs/summary/kept"] == [(0, summary["kept"])]
    assert scalars["pairs/summary/outcomes/bc_fail/da_ok"] == [(0, summary["outcomes"]["bc_fail/da_ok"])]


def test_mapper_scalars_are_its_curves_autoencoders_included(run):
    for kind, models in (("dm", ["dm"]), ("sam", ["sigma_all", "h"])):
        rows = read_csv(run.mapper_curves(kind), columns=CURVE_COLUMNS)
        assert list(dict.fromkeys(r["model"] for r in rows)) == models
        scalars = _read(run, f"mapper/{kind}")
        for model in models:
            mine = [r for r in rows if r["model"] == model]
            for key in ("train_loss", "val_loss"):
                assert scalars[f"mapper/{kind}/{model}/{key}"] == list(
                    zip([r["epoch"] for r in mine], _f32(r[key] for r in mine))
                )
        last = [r for r in rows if r["val_mse_weights"] != ""]  # the whole mapping, after the last model's epochs
        assert scalars[f"mapper/{kind}/val_mse_weights"] == list(
            zip([r["epoch"] for r in last], _f32(r["val_mse_weights"] for r in last))
        )


def test_evaluation_scalars_equal_the_tables(run):
    scalars = _read(run, "eval/mdm")
    rows = read_csv(run.eval_table("mdm"))
    for method in ("bc", "dm", "sam"):
        mine = [r for r in rows if r["method"] == method]
        for key in ("success", "reward", "expert_queries"):
            assert scalars[f"eval/mdm/{method}/{key}"] == [(r["seed"], float(r[key])) for r in mine]
        assert scalars[f"eval/mdm/{method}/mean/success"] == [(0, *_f32([np.mean([r["success"] for r in mine])]))]
    mdi = {r["method"]: r for r in read_csv(run.eval_table("mdi"))}
    scalars = _read(run, "eval/mdi")
    for method, row in mdi.items():
        assert scalars[f"eval/mdi/{method}/one_shot_reward"] == [(500, row["one_shot_reward"])]
        assert scalars[f"eval/mdi/{method}/expert_queries"] == [(500, row["expert_queries"])]


def test_benchmark_scalars_equal_its_table_and_summary(run):
    scalars = _read(run, "benchmark")
    for r in read_csv(run.benchmark_table):
        group = r["method"] if r["setting"] == "" else f"{r['method']}@{r['setting']}"
        assert scalars[f"benchmark/{group}/success"] == [(400, float(r["success"]))]
        assert scalars[f"benchmark/{group}/expert_queries"] == [(400, r["expert_queries"])]
    assert "benchmark/dagger-random@0.5/success" in scalars and "benchmark/mdm-sam/reward" in scalars
    summary = json.loads(run.benchmark_summary.read_text())
    for e in summary["entries"]:
        assert (round(e["mean_queries"]), e["success_rate"]) in scalars[f"benchmark/{e['method']}/success_vs_queries"]
    assert scalars["benchmark/meta_training_queries/pistar"] == [(0, summary["meta_training_queries"]["pistar"])]


def test_success_against_queries_runs_from_the_fewest_queries(run, tmp_path):
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(run.root, layout.root)
    summary = json.loads(layout.benchmark_summary.read_text())
    first = summary["entries"][0]
    summary["entries"].insert(
        0, {**first, "mean_queries": first["mean_queries"] + 100}
    )  # a costlier setting listed first
    layout.benchmark_summary.write_text(json.dumps(summary))
    curves: dict[str, list[int]] = {}
    for tag, _, step in benchmark_scalars(layout):
        if tag.endswith("/success_vs_queries"):
            curves.setdefault(tag, []).append(step)
    assert any(len(steps) > 1 for steps in curves.values())
    assert all(steps == sorted(steps) for steps in curves.values()), curves


def test_a_rerun_replaces_the_points_instead_of_adding_to_them(run, presets, tmp_path):
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(run.root, layout.root)
    before = {namespace: _read(layout, namespace) for namespace in NAMESPACES}
    _reproduce(layout.root, presets)  # resumes every stage; the run's config keeps log: tensorboard
    assert {namespace: _read(layout, namespace) for namespace in NAMESPACES} == before
    assert len(list(layout.tb_dir.rglob("events.out.tfevents.*"))) == len(NAMESPACES)
    assert not list(layout.root.glob(".*.tmp*"))  # no staging folder left behind


def test_off_by_default_writes_nothing_and_never_imports_tensorboard(run, presets, tmp_path, monkeypatch):
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(run.root, layout.root, ignore=shutil.ignore_patterns("tb"))
    layout.config.write_text(
        layout.config.read_text().replace("log: tensorboard\n", "")
    )  # as a run made before the key
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # any import of it now fails
    _reproduce(layout.root, presets)
    assert not layout.tb_dir.exists()
    assert "log: none\n" in layout.config.read_text()


def test_log_none_turns_it_off(run, presets, tmp_path):
    layout = RunLayout(tmp_path / "run")
    shutil.copytree(run.root, layout.root, ignore=shutil.ignore_patterns("tb"))
    out = _reproduce(layout.root, presets, "--log", "none")
    assert not layout.tb_dir.exists() and "tensorboard --logdir" not in out


def _one_error_line(args: list[str]) -> str:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_a_missing_tensorboard_is_one_line_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)
    with pytest.raises(UserError, match="needs the tensorboard package"):
        require_tensorboard()
    line = _one_error_line(["config", "show", "--task", "carracing", "--preset", "ci", "--set", "log=tensorboard"])
    assert INSTALL in line and INSTALL == 'pip install -c constraints.txt -e ".[tensorboard]"'


def test_an_unknown_log_is_one_line_naming_the_choices():
    line = _one_error_line(["config", "show", "--task", "carracing", "--preset", "ci", "--set", "log=wandb"])
    assert "log must be one of none, tensorboard, got 'wandb'" in line


def test_pistar_scalars_carry_the_epoch_selection(tmp_path):
    layout = RunLayout(tmp_path)
    layout.pistar_dir.mkdir(parents=True)
    summary = {"episodes": 2, "successes": 1, "success_rate": 0.5}
    choice = {
        "epoch": 4,
        "successes": 3,
        "episodes": 5,
        "history": [{"epoch": 4, "successes": 3, "episodes": 5}, {"epoch": 8, "successes": 2, "episodes": 5}],
    }
    layout.pistar_metrics.write_text(
        json.dumps(
            {
                "own_seeds": summary,
                "unseen_seeds": summary,
                "rounds": [],
                "bc_epoch_losses": [0.5] * 8,
                "expert_queries": 7,
                "bc_selection": choice,
            }
        )
    )
    scalars = pistar_scalars(layout)
    assert [s for s in scalars if s[0].startswith("select/")] == [
        ("select/successes", 3, 4),
        ("select/successes", 2, 8),
        ("select/chosen_epoch", 4, 0),
    ]


def test_rows_from_a_share_of_the_demonstration_are_points_of_their_own(tmp_path):
    from metadagger.evaluation.tensorboard import table_scalars

    table = tmp_path / "queries.csv"
    table.write_text(
        "method,setting,demo_fraction,seed,success,expert_queries\n"
        "bc,,1.0,400,1,100\nbc,,0.5,400,0,50\nbc,,1.0,401,1,110\nbc,,0.5,401,0,55\n"
    )
    scalars: dict[str, list[tuple[int, float]]] = {}
    for tag, value, step in table_scalars(table):
        scalars.setdefault(tag, []).append((step, value))
    assert scalars["bc/expert_queries"] == [(400, 100.0), (401, 110.0)]
    assert scalars["bc@demo0.5/expert_queries"] == [(400, 50.0), (401, 55.0)]
    assert scalars["bc/mean/success"] == [(0, 1.0)] and scalars["bc@demo0.5/mean/success"] == [(0, 0.0)]
    assert not any("demo_fraction" in tag for tag in scalars)
