"""Mapper hyperparameter search: the study on disk, determinism, resume, errors and the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from mapping_data import synthetic_split, tiny_config
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.mapping import tune as tune_module
from metadagger.mapping.config import MapperConfig, paper_config
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.search_space import baseline_params, check_tunable, search_space, trial_config
from metadagger.mapping.train import evaluate_mapping, fit_mapper
from metadagger.mapping.tune import tune_mapper
from metadagger.metal_dagger.pairs import pair_stamp
from metadagger.metal_dagger.store import PairStore
from metadagger.pipeline.run_config import init_run, load_run
from metadagger.pipeline.stage_inputs import run_task
from metadagger.policies import make_policy
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.yaml_config import build, to_dict

optuna = pytest.importorskip("optuna")

runner = CliRunner()
BASE = tiny_config("dm", epochs=2)
TWO = StageOptions(workers=2, progress=False)


def _tune(folder: Path, split, *, trials: int, base: MapperConfig = BASE, options: StageOptions = TWO, **kwargs):
    return tune_mapper(
        split,
        base,
        study=folder / f"{base.kind}.db",
        summary=folder / f"{base.kind}.yaml",
        trials=trials,
        options=options,
        **kwargs,
    )


def _trials(folder: Path, kind: str = "dm") -> list[tuple]:
    study = optuna.load_study(study_name=tune_module.STUDY_NAME, storage=f"sqlite:///{folder / f'{kind}.db'}")
    return [(t.state.name, t.params, t.value) for t in study.trials]


def _complete(folder: Path) -> list[tuple]:
    return [(params, value) for state, params, value in _trials(folder) if state == "COMPLETE"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory, split) -> Path:
    """A dm study of 4 trials run at once, two workers."""
    folder = tmp_path_factory.mktemp("reference")
    _tune(folder, split, trials=4)
    return folder


def test_a_study_writes_its_database_and_the_best_settings(tmp_path, split):
    base = tiny_config("sam", epochs=2, ae_epochs=2)
    result = _tune(tmp_path, split, trials=3, base=base, base_overrides={"batch_size": 10})
    assert (tmp_path / "sam.db").is_file() and result.completed == result.ran == 3
    summary = yaml.safe_load((tmp_path / "sam.yaml").read_text())
    assert summary["best"]["trial"] == result.best_trial and summary["best"]["value"] == result.best_value
    assert summary["baseline"]["trial"] == 0  # trial 0 is the base config itself
    assert set(summary["made_from"]) >= {"pairs_fingerprint", "seed", "space", "val_seeds", "base"}
    assert summary["made_from"]["val_seeds"] == list(split.val_seeds)
    assert set(summary["made_from"]["space"]) == set(search_space("sam", base))
    # the --set item holds the run's own overrides and every tuned field, and gives the best trial's config
    assert summary["set"] == result.set_item and result.set_item.startswith("mappers.sam={")
    overrides = yaml.safe_load(result.set_item.partition("=")[2])
    assert overrides == summary["overrides"] == result.overrides and overrides["batch_size"] == 10
    config = build(MapperConfig, {**to_dict(base), **overrides})
    assert config == trial_config(base, summary["best"]["params"])
    # and a mapper trained here with it scores what the worker's trial scored
    mapper, _ = fit_mapper(split, config, progress=False)
    assert evaluate_mapping(mapper, split.w_bc_val, split.w_da_val)["mse"] == result.best_value


def test_the_same_seed_gives_the_same_study_and_a_resumed_study_runs_only_the_missing_trials(
    reference, tmp_path, split
):
    assert _tune(tmp_path, split, trials=2).ran == 2
    resumed = _tune(tmp_path, split, trials=4)
    assert (resumed.ran, resumed.completed) == (2, 4)
    assert _trials(tmp_path) == _trials(reference)
    assert _tune(tmp_path, split, trials=3).ran == 0  # already holds more
    other = _tune(tmp_path / "other", split, trials=4, seed=1)
    assert _complete(tmp_path / "other")[1:] != _complete(reference)[1:]  # trial 0 is the base config in both
    assert other.completed == 4


class _KilledAfter:
    """An in-process executor whose driver dies (KeyboardInterrupt) after ``results`` results."""

    workers = 2

    def __init__(self, results: int) -> None:
        self.results = results

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass

    def imap_unordered(self, fn, items):
        for item in items:
            if self.results == 0:
                raise KeyboardInterrupt
            self.results -= 1
            yield fn(item)


def test_a_killed_study_reruns_its_interrupted_trials_and_then_matches_an_uninterrupted_one(
    reference, tmp_path, split, monkeypatch
):
    with monkeypatch.context() as patch:
        patch.setattr(tune_module, "make_executor", lambda *a, **k: _KilledAfter(3))
        with pytest.raises(KeyboardInterrupt):
            _tune(tmp_path, split, trials=4)
    assert [state for state, _, _ in _trials(tmp_path)] == ["COMPLETE"] * 3 + ["RUNNING"]
    resumed = _tune(tmp_path, split, trials=4)
    assert (resumed.ran, resumed.completed) == (1, 4)
    states = [state for state, _, _ in _trials(tmp_path)]
    assert states == ["COMPLETE"] * 3 + ["FAIL", "COMPLETE"]
    assert _complete(tmp_path) == _complete(reference)


def test_a_study_resumes_only_with_its_pairs_and_untuned_settings(tmp_path, split):
    _tune(tmp_path, split, trials=1)
    with pytest.raises(UserError, match=r"made from other inputs \(pairs: changed\); pass --rebuild"):
        _tune(tmp_path, synthetic_split(seed=1), trials=2)
    with pytest.raises(UserError, match=r"base.batch_size: 10 -> 20"):
        _tune(tmp_path, split, trials=2, base=tiny_config("dm", epochs=2, batch_size=20))
    with pytest.raises(UserError, match=r"seed: 0 -> 3"):
        _tune(tmp_path, split, trials=2, seed=3)
    # a tuned field (what --apply writes) changes nothing; --rebuild starts a new study
    assert _tune(tmp_path, split, trials=1, base=tiny_config("dm", epochs=2, lr=1e-3)).ran == 0
    rebuilt = _tune(
        tmp_path, synthetic_split(seed=1), trials=1, options=StageOptions(workers=2, progress=False, rebuild=True)
    )
    assert (rebuilt.ran, rebuilt.completed) == (1, 1)


@pytest.mark.parametrize(
    ("kind", "why"),
    [
        ("ridge", "is fitted in closed form"),
        ("mean-da", "is a control"),
        ("pistar-head", "is a control"),
        ("nope", "is not a mapper kind"),
    ],
)
def test_kinds_without_hyperparameters_are_one_line_errors(kind, why):
    with pytest.raises(UserError, match=rf"--kind '{kind}' {why}.*; tune one of dm, sam, tam, e.g. `metadagger tune"):
        check_tunable(kind)


def test_bad_requests_are_user_errors(tmp_path, split, monkeypatch):
    with pytest.raises(UserError, match="trials must be an integer >= 1, got 0"):
        _tune(tmp_path, split, trials=0)
    (tmp_path / "dm.db").write_text("not a database")
    with pytest.raises(UserError, match=r"dm.db is not an Optuna study \(file is not a database\); pass --rebuild"):
        _tune(tmp_path, split, trials=1)
    no_val = synthetic_split(n_val=0)
    with pytest.raises(UserError, match="the split has none; set pairs.val_fraction above 0"):
        _tune(tmp_path, no_val, trials=1)
    monkeypatch.setitem(__import__("sys").modules, "optuna", None)  # as if not installed
    with pytest.raises(UserError, match=r'needs Optuna.*pip install -c constraints.txt -e "\.\[tune\]"'):
        _tune(tmp_path, split, trials=1)


def _run_folder(tmp_path: Path) -> Path:
    """A CarRacing ci run with a pi* and 12 current pairs (synthetic heads of pi*'s head length)."""
    run = tmp_path / "run"
    config = init_run(run, "carracing", "ci", overrides=["pairs.seeds=1000-1011"])
    task, layout = run_task(config), RunLayout(run)
    pistar = make_policy(task, seed=0)
    pistar.save(layout.pistar)
    stamp = pair_stamp(task, layout, config.pairs)
    data = synthetic_split(n_train=12, n_val=0, dim=len(pistar.head_vector()))
    outcome = {"success": False, "reward": 0.0, "steps": 1, "expert_queries": 1}
    store = PairStore(layout.pairs_dir)
    for i, seed in enumerate(config.pairs.seeds):
        store.write(
            seed, data.w_bc_train[i], data.w_da_train[i], {"bc": outcome, "da": outcome, "kept": True, "stamp": stamp}
        )
    return run


def _cli(args: list) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_the_command_tunes_prints_the_set_item_and_applies_it_for_train_mapper(tmp_path):
    run = _run_folder(tmp_path)
    layout = RunLayout(run)
    out = _cli(["tune", "--out", run, "--kind", "dm", "--trials", 2, "--workers", 2])
    assert layout.tune_study("dm").is_file() and layout.tune_summary("dm").is_file()
    summary = yaml.safe_load(layout.tune_summary("dm").read_text())
    assert f"--set '{summary['set']}'" in out and "2 trials ran now" in out
    assert "tune/dm: trial 1:" in out  # a progress line per trial

    out = _cli(["tune", "--out", run, "--kind", "dm", "--trials", 2, "--apply"])
    assert "0 trials ran now" in out and f"applied to {layout.config}" in out
    config = load_run(run)
    assert config.mappers["dm"] == summary["overrides"]
    assert {"epochs", "lr", "hidden"} <= set(config.mappers["dm"])  # replaced the preset's dm section
    _cli(["train-mapper", "--out", run, "--kind", "dm", "--rebuild"])
    mapper = load_mapper(layout.mapper("dm"))
    assert mapper.config == to_dict(config.mapper_config("dm"))
    split = PairStore(layout.pairs_dir).load_split(
        val_fraction=config.pairs.val_fraction, seed=config.split_seed, seeds=config.pairs.seeds
    )
    assert evaluate_mapping(mapper, split.w_bc_val, split.w_da_val)["mse"] == summary["best"]["value"]

    result = runner.invoke(app, ["tune", "--out", str(run), "--kind", "ridge"])
    assert result.exit_code == 2 and result.output.startswith("error: --kind 'ridge' is fitted in closed form")
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize("kind", ["dm", "sam", "tam"])
def test_the_space_holds_the_papers_settings_and_bounds_epochs_by_the_runs(kind):
    paper = paper_config(kind)
    space = search_space(kind, paper)
    assert baseline_params(paper, space) is not None  # trial 0 can be the paper's config
    assert ("latent" in space) == (kind != "dm")
    assert (space["epochs"].low, space["epochs"].high) == (paper.epochs // 4, 2 * paper.epochs)
