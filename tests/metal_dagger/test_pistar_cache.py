"""pi* made once per machine: a run takes the cached pi* of its config (a family's run the one its
base task's run made), byte for byte what training it would make, and says where it was made."""

from __future__ import annotations

import dataclasses
import json

import pytest
from toy_task import CorridorFamily, RunCorridorTask

from metadagger.evaluation.report.run import pistar_section
from metadagger.imitation.bc import BCConfig
from metadagger.metal_dagger import pistar as pistar_module
from metadagger.metal_dagger.pistar import CACHE_KIND, PiStarConfig, pistar_cache_stamp, pistar_changes, train_pistar
from metadagger.runfolder import machine_cache
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.machine_cache import CACHE_ENV, cached, entry_folder, made_record

PISTAR = PiStarConfig(seeds=(0, 1), eval_seeds=(100,), dagger_rounds=1, bc=BCConfig(lr=3e-3, batch_size=16, epochs=2))
NAMES = ("policy.safetensors", "metrics.json")


@pytest.fixture(autouse=True)
def committed(monkeypatch) -> None:
    """Every test runs as from a commit (a tree with uncommitted changes has no cache)."""
    monkeypatch.setattr(machine_cache, "source_revision", lambda: "0123abc")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def no_training(monkeypatch) -> None:
    """Make any fit of pi* fail the test: what follows must take pi* from the cache."""

    def refuse(*args, **kwargs):
        raise AssertionError("pi* was trained, not taken from the cache")

    monkeypatch.setattr(pistar_module, "fit_or_resume", refuse)


def test_a_family_run_takes_the_pistar_its_base_tasks_run_made_and_says_where(cache, tmp_path, monkeypatch):
    base, family = RunLayout(tmp_path / "base"), RunLayout(tmp_path / "family")
    metrics = train_pistar(RunCorridorTask(), PISTAR, base, progress=False)
    entry = cached(CACHE_KIND, pistar_cache_stamp(RunCorridorTask(), PISTAR), NAMES)
    assert entry is not None and not base.pistar_origin.exists()
    assert made_record(entry)["run"] == str(base.root.resolve()) and made_record(entry)["seconds"] > 0

    with monkeypatch.context() as patched:
        no_training(patched)
        assert train_pistar(CorridorFamily(), PISTAR, family, progress=False) == metrics
    assert family.pistar.read_bytes() == base.pistar.read_bytes()
    assert family.pistar_metrics.read_bytes() == base.pistar_metrics.read_bytes()
    origin = json.loads(family.pistar_origin.read_text())
    assert origin["run"] == str(base.root.resolve()) and origin["cache"] == str(entry)
    assert pistar_changes(CorridorFamily(), PISTAR, family) == []  # the run's own stamp: its later stages read it
    assert any("taken from the machine's cache" in line for line in pistar_section(family))

    # what the family's run would have trained, with the cache off, is the same file
    monkeypatch.setenv(CACHE_ENV, "off")
    alone = RunLayout(tmp_path / "alone")
    train_pistar(CorridorFamily(), PISTAR, alone, progress=False)
    assert alone.pistar.read_bytes() == family.pistar.read_bytes() and not alone.pistar_origin.exists()


def test_another_config_trains_its_own_pistar_and_keeps_it_beside_the_first(cache, tmp_path):
    train_pistar(RunCorridorTask(), PISTAR, RunLayout(tmp_path / "one"), progress=False)
    longer = dataclasses.replace(PISTAR, bc=dataclasses.replace(PISTAR.bc, epochs=3))
    two = RunLayout(tmp_path / "two")
    train_pistar(RunCorridorTask(), longer, two, progress=False)
    assert not two.pistar_origin.exists() and (two.pistar_rounds / "round_1.safetensors").is_file()  # trained here
    assert len(list((cache / CACHE_KIND).iterdir())) == 2


def test_a_damaged_entry_is_trained_again_and_mended(cache, tmp_path):
    one = RunLayout(tmp_path / "one")
    train_pistar(RunCorridorTask(), PISTAR, one, progress=False)
    entry = entry_folder(CACHE_KIND, pistar_cache_stamp(RunCorridorTask(), PISTAR))
    (entry / "policy.safetensors").write_bytes(b"not a policy")
    two = RunLayout(tmp_path / "two")
    train_pistar(RunCorridorTask(), PISTAR, two, progress=False)
    assert not two.pistar_origin.exists() and two.pistar.read_bytes() == one.pistar.read_bytes()
    assert (entry / "policy.safetensors").read_bytes() == one.pistar.read_bytes()
    assert made_record(entry)["run"] == str(two.root.resolve())


def test_a_pistar_finished_with_the_cache_off_is_kept_when_its_stage_runs_again(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(CACHE_ENV, "off")
    made = RunLayout(tmp_path / "made")
    train_pistar(RunCorridorTask(), PISTAR, made, progress=False)
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    no_training(monkeypatch)
    train_pistar(RunCorridorTask(), PISTAR, made, progress=False)  # finished: nothing is trained
    entry = cached(CACHE_KIND, pistar_cache_stamp(CorridorFamily(), PISTAR), NAMES)
    assert entry is not None and (entry / "policy.safetensors").read_bytes() == made.pistar.read_bytes()
    assert made_record(entry)["seconds"] is None  # a folder made in code records no stage time
    taken = RunLayout(tmp_path / "taken")
    capsys.readouterr()
    train_pistar(CorridorFamily(), PISTAR, taken, progress=True)
    assert taken.pistar.read_bytes() == made.pistar.read_bytes()
    said = (
        f"pi*: taken from the machine's cache, made by run {made.root.resolve()} (METADAGGER_CACHE=off trains it here)"
    )
    assert said in capsys.readouterr().err


@pytest.mark.parametrize("base", ["carracing", "fetch"])
@pytest.mark.parametrize("preset", ["quick", "paper"])
def test_the_family_presets_share_pi_star_with_their_base_task(preset, base):
    """A family's preset keeps its base task's pistar settings, so one pi* serves both runs."""
    from metadagger.pipeline.run_config import resolve_config
    from metadagger.tasks import make_task

    stamps = []
    for name in (base, f"{base}-family"):
        config = resolve_config(name, preset)
        stamps.append(pistar_cache_stamp(make_task(name, max_episode_steps=config.max_episode_steps), config.pistar))
    assert stamps[0] == stamps[1]
