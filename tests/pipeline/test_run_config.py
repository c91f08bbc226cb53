"""Bad run configs, presets files and --set values: one clear line before any work, and a refused
command leaves the run's config.yaml as it was."""

from __future__ import annotations

import pytest
import yaml
from test_stages import _refused

from metadagger.errors import UserError
from metadagger.evaluation.report.build import build_report
from metadagger.pipeline.run_config import RunConfig, init_run, load_run, resolve_config
from metadagger.pipeline.stage_runs import records_config
from metadagger.runfolder.layout import RunLayout
from metadagger.version import __version__


@pytest.fixture
def run(tmp_path) -> RunLayout:
    """A started CarRacing ci run: its config.yaml and nothing else."""
    init_run(tmp_path / "run", "carracing", "ci")
    return RunLayout(tmp_path / "run")


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        (b"\x00\xff\xfe garbage", "not UTF-8 text: byte 0xff at offset 1"),
        (b"task: carracing\npairs: {seeds: [1, 2}\n", "but got '}' at line 2, column 21"),
        (b"- carracing\n", "expected a mapping, got list"),
    ],
)
def test_an_unreadable_config_yaml_is_one_line_for_stages_and_report(run, text, problem):
    run.config.write_bytes(text)
    for call in (lambda: load_run(run.root), lambda: build_report(run)):
        with pytest.raises(UserError) as error:
            call()
        message = str(error.value)
        assert "\n" not in message
        assert (
            f"{run.config} is not a readable YAML config (" in message
            and problem in message
            and "start a new run folder" in message
        )
    _refused(["pairs", "--out", run.root], "is not a readable YAML config", problem)
    _refused(["report", "--out", run.root], "is not a readable YAML config", problem)


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("presets: {mine: 5}\n", ("preset 'mine' is 5, not a mapping of stage sections", "mine: {pairs:")),
        ("presets: {mine: }\n", ("preset 'mine' is None, not a mapping of stage sections",)),
        ("presets: {}\n", ("has no presets: expected a top-level 'presets:' mapping", "docs/custom_task.md")),
        ("presets: {small: {}}\n", ("has no preset 'mine': expected one of small; pass one with --preset",)),
        ("presets: [\n", ("is not a readable YAML presets file (", "at line 2, column 1")),
    ],
)
def test_a_bad_presets_file_is_one_line(tmp_path, text, needles):
    presets = tmp_path / "p.yaml"
    presets.write_text(text)
    _refused(["config", "show", "--presets", presets, "--preset", "mine"], *needles)
    _refused(["reproduce", "--presets", presets, "--preset", "mine", "--out", tmp_path / "run"], *needles)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("override", "needle"),
    [
        ("split_seed=-1", "split_seed: seed -1 is negative; use seeds >= 0"),
        ("pairs.bc.seed=-1", "pairs.bc.seed: seed -1 is negative"),
        ("mappers.dm.seed=-2", "mappers.dm.seed: seed -2 is negative"),
        ("evaluate.seeds=[-1]", "evaluate.seeds: seed -1 is negative"),
        ("benchmark.seeds=[-1]", "benchmark.seeds: seed -1 is negative"),
        ("pairs.seeds=[2000, 2000]", "pairs.seeds: seed 2000 appears twice; list each seed once"),
        ("pistar.select_seeds=[7, 7]", "pistar.select_seeds: seed 7 appears twice"),
        ("pairs.seeds=2000-2001,2001", "pairs.seeds: bad seed list '2000-2001,2001': seed 2001 appears twice"),
        ("pairs.bc.lr=.inf", "pairs.bc.lr: expected a finite number, got inf"),
        ("mappers.dm.lr=.inf", "mappers.dm.lr: expected a finite number, got inf"),
        ("pairs.bc.lr=.nan", "pairs.bc.lr: expected a finite number, got nan"),
        ("diagnose.scaling=[-.inf]", "diagnose.scaling: expected a finite number, got -inf"),
        ("mappers.dm.hidden=bogus", "mappers.dm.hidden: expected a list of int, got 'bogus'"),
        ("task=fetch", "bad --set 'task=fetch': the task is chosen with --task, not --set"),
        ("preset=bogus", "bad --set 'preset=bogus': the preset is chosen with --preset, not --set"),
    ],
)
def test_bad_field_values_are_refused_when_the_config_is_built(override, needle):
    with pytest.raises(UserError, match="^[^\n]*$") as error:
        resolve_config("carracing", "ci", overrides=[override])
    assert needle in str(error.value)
    _refused(["config", "show", "--task", "carracing", "--preset", "ci", "--set", override], needle)


def test_seed_fields_still_take_seed_lists_and_counts_are_not_seeds():
    config = resolve_config(
        "carracing", "ci", overrides=["pairs.seeds=1000-1002,1007", "evaluate.seeds=5000", "diagnose.noise_seeds=0"]
    )
    assert config.pairs.seeds == (1000, 1001, 1002, 1007) and config.evaluate.seeds == (5000,)
    assert config.diagnose.noise_seeds == 0


def test_a_partial_nested_section_keeps_the_stage_defaults_it_does_not_name(tmp_path):
    from metadagger.imitation.bc import BCConfig
    from metadagger.metal_dagger.pairs import PairConfig
    from metadagger.metal_dagger.pistar import PiStarConfig

    presets = tmp_path / "p.yaml"
    presets.write_text("presets: {mine: {pistar: {bc: {epochs: 5}}, pairs: {bc: {head_init: shared}}}}\n")
    config = resolve_config("carracing", "mine", presets)
    stage_bc = PiStarConfig().bc
    assert config.pistar.bc == BCConfig(**{**vars(stage_bc), "epochs": 5}) and stage_bc != BCConfig()
    assert config.pairs.bc == BCConfig(**{**vars(PairConfig().bc), "head_init": "shared"})
    assert config.pairs.dagger_bc == PairConfig().dagger_bc


def test_a_run_config_naming_its_task_and_preset_still_loads(run):
    assert "task: carracing\npreset: ci\n" in run.config.read_text()
    assert (load_run(run.root).task, load_run(run.root).preset) == ("carracing", "ci")


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["pistar", "--task", "carracing", "--preset", "ci", "--set", "task=fetch"], "bad --set 'task=fetch'"),
        (["pistar", "--task", "fetch", "--preset", "ci"], "holds task 'carracing' preset 'ci', not 'fetch' 'ci'"),
        (["pairs", "--set", "pairs.dagger_rounds=4"], "pi* not found"),
        (["evaluate", "--protocol", "mdi", "--set", "evaluate.oneshot=false"], "has no mdi section"),
    ],
)
def test_a_refused_command_leaves_config_yaml_as_it_was(run, args, needle):
    before = run.config.read_bytes()
    _refused([*args, "--out", run.root], needle)
    assert run.config.read_bytes() == before


def test_a_stage_writes_the_config_it_runs_with_and_puts_it_back_when_it_refuses(run):
    before = run.config.read_bytes()
    changed = load_run(run.root, ["pairs.dagger_rounds=4"])
    seen = []

    @records_config
    def stage(layout: RunLayout, config: RunConfig, *, refuse: bool) -> None:
        seen.append(load_run(layout.root).pairs.dagger_rounds)
        if refuse:
            raise UserError("refused")

    with pytest.raises(UserError, match="refused"):
        stage(run, changed, refuse=True)
    assert run.config.read_bytes() == before
    stage(run, changed, refuse=False)
    assert seen == [4, 4] and load_run(run.root) == changed


def test_config_yaml_records_the_version_that_made_the_folder_and_no_set_changes_it(run):
    assert run.config.read_text().startswith(f"metadagger_version: {__version__}\n")
    assert load_run(run.root).metadagger_version == __version__
    _refused(
        ["pairs", "--out", run.root, "--set", "metadagger_version=9.9.9"],
        "bad --set 'metadagger_version=9.9.9'",
        "cannot be set",
    )


@pytest.mark.parametrize(
    ("recorded", "made_by"),
    [
        (None, "a metadagger version before 0.2"),
        ("0.1.0", "metadagger 0.1.0"),
        ("9.0.0", "metadagger 9.0.0"),
    ],
    ids=["unrecorded", "older", "newer"],
)
def test_a_run_folder_of_another_version_is_one_line_that_says_what_to_do(run, recorded, made_by):
    data = yaml.safe_load(run.config.read_text())
    if recorded is None:
        del data["metadagger_version"]
    else:
        data["metadagger_version"] = recorded
    run.config.write_text(yaml.safe_dump(data, sort_keys=False))
    before = run.config.read_bytes()
    expected = (
        f"{run.config} was made by {made_by}; this is {__version__}: start a new run folder "
        f"(metadagger reproduce --task carracing --preset ci --out NEW) or use {made_by}"
    )
    with pytest.raises(UserError) as error:
        load_run(run.root)
    assert str(error.value) == expected
    assert _refused(["pairs", "--out", run.root]) == f"error: {expected}"
    assert _refused(["reproduce", "--task", "carracing", "--preset", "ci", "--out", run.root]) == f"error: {expected}"
    assert run.config.read_bytes() == before


def test_a_run_folder_of_another_patch_version_loads(run):
    major, minor, _ = __version__.split(".")
    run.config.write_text(
        run.config.read_text().replace(f"metadagger_version: {__version__}", f"metadagger_version: {major}.{minor}.99")
    )
    assert load_run(run.root).metadagger_version == f"{major}.{minor}.99"


def test_a_registry_run_from_before_the_renames_is_one_line_that_says_what_to_do(tmp_path):
    """The config of registry run ``fetch-family-quick`` as 0.2 made it (its pi* section still called
    ``groundtruth``), in a run folder: every command that reads it says, in one line, to start a new
    folder, and writes nothing."""
    from pathlib import Path

    old = Path(__file__).parent / "data" / "fetch-family-quick-0.2.0.yaml"
    assert "groundtruth:" in old.read_text()
    run = RunLayout(tmp_path / "old")
    run.root.mkdir()
    run.config.write_bytes(old.read_bytes())
    expected = (
        f"{run.config} was made by metadagger 0.2.0; this is {__version__}: start a new run folder "
        "(metadagger reproduce --task fetch-family --preset quick --out NEW) or use metadagger 0.2.0"
    )
    for args in (["pairs", "--out", run.root], ["benchmark", "--out", run.root], ["report", "--out", run.root]):
        assert _refused(args) == f"error: {expected}"
    assert [p.name for p in run.root.iterdir()] == ["config.yaml"]
    assert run.config.read_bytes() == old.read_bytes()


def test_a_run_folder_of_this_version_written_before_a_key_was_renamed_reads_it_by_its_name_now(run):
    """``benchmark.ceiling`` is ``benchmark.oracle`` now: a folder that says ``ceiling: false`` resumes
    with the oracle rule off; a preset or ``--set`` that uses the old name is refused naming the new."""
    data = yaml.safe_load(run.config.read_text())
    data["benchmark"] = {**(data.get("benchmark") or {}), "ceiling": False}
    data["benchmark"].pop("oracle", None)
    run.config.write_text(yaml.safe_dump(data, sort_keys=False))
    config = load_run(run.root)
    assert config.benchmark.oracle is False
    assert "dagger-oracle" not in config.benchmark.gated()
    message = _refused(["pairs", "--out", run.root, "--set", "benchmark.ceiling=true"])
    assert "unknown field(s) ceiling (ceiling is now oracle)" in message


@pytest.mark.parametrize("task", ["carracing", "fetch", "carracing-family", "fetch-family"])
@pytest.mark.parametrize("preset", ["quick", "paper"])
def test_the_spare_seed_is_none_the_run_names(task, preset):
    config = resolve_config(task, preset)
    named = config.pistar.used_seeds | set(config.pairs.seeds) | config.unseen_seeds
    assert config.spare_seed not in named and config.spare_seed == max(named) + 1
    assert set(config.benchmark.confirm_seeds) <= config.unseen_seeds
