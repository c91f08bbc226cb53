"""The CLI: user errors give one clear line and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from toy_task import TINY_PRESETS, CorridorTask, RunCorridorTask
from typer.testing import CliRunner

from metadagger.cli.entry import main
from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.pipeline.run_config import init_run
from metadagger.policies import make_policy
from metadagger.runfolder.layout import RunLayout
from metadagger.version import __version__

runner = CliRunner()
VERSION = f"metadagger_version: {__version__}\n"
"""The line that every run folder's config.yaml starts with."""


def _fails_cleanly(args: list[str], *needles: str) -> str:
    """Run the CLI; assert exit code 2 and one `error:` line holding every needle; return it."""
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    out = result.output
    assert "Traceback" not in out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, out
    for needle in needles:
        assert needle in errors[0]
    return out


def test_unknown_task_is_one_clear_line():
    out = _fails_cleanly(["expert", "--task", "nope", "--seeds", "0"], "unknown task 'nope'", "carracing")
    assert len([line for line in out.splitlines() if line.strip()]) == 1


@pytest.mark.parametrize(
    "args, needles",
    [
        (["pairs", "--out", "RUN", "--workers", "abc"], ["'--workers'", "integer", "`metadagger pairs --help`"]),
        (["pairs"], ["Missing option '--out'", "`metadagger pairs --help`"]),
        (["pairz"], ["No such command 'pairz'", "`metadagger --help`"]),
        (["pairs", "--out", "RUN", "--bogus"], ["No such option: --bogus", "`metadagger pairs --help`"]),
    ],
)
def test_command_line_usage_errors_are_one_line(capsys, args, needles):
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    for needle in needles:
        assert needle in lines[0]


def test_help_and_a_finished_command_exit_as_usual(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["pairs", "--help"])
    assert exit_.value.code == 0 and "--workers" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_:
        main(["config", "show", "--task", "carracing", "--preset", "quick"])
    assert exit_.value.code == 0 and "pairs:" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_:
        main(["expert", "--task", "nope", "--seeds", "0"])
    assert exit_.value.code == 2 and capsys.readouterr().err.startswith("error: unknown task 'nope'")


def test_an_interrupt_exits_130_and_a_bug_is_its_own_traceback(monkeypatch, capsys):
    def interrupted(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr("metadagger.pipeline.run_config.resolve_config", interrupted)
    with pytest.raises(SystemExit) as exit_:
        main(["config", "show", "--task", "carracing", "--preset", "quick"])
    assert exit_.value.code == 130 and "Traceback" not in capsys.readouterr().err  # the shell's code for Ctrl-C

    def broken(*_):
        raise ZeroDivisionError("a bug, not a user error")

    monkeypatch.setattr("metadagger.pipeline.run_config.resolve_config", broken)
    with pytest.raises(ZeroDivisionError, match="a bug, not a user error"):
        main(["config", "show", "--task", "carracing", "--preset", "quick"])


def test_a_bad_log_value_names_the_option(tmp_path):
    _fails_cleanly(
        ["reproduce", "--out", str(tmp_path / "run"), "--log", "bogus"],
        "--log must be one of none, tensorboard, got 'bogus'",
    )
    assert not (tmp_path / "run").exists()


def test_bad_seed_list_names_the_value():
    _fails_cleanly(["expert", "--task", "carracing", "--seeds", "9-3"], "bad seed list '9-3'")


def test_unknown_preset_names_the_allowed_ones(tmp_path):
    _fails_cleanly(
        ["pistar", "--preset", "huge", "--out", str(tmp_path / "r")],
        "unknown preset 'huge'",
        "quick",
        "--presets FILE",
    )


def test_bad_config_value_in_a_run_config(tmp_path):
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\npairs: {dagger_rounds: 0}\n")
    _fails_cleanly(["pairs", "--out", str(tmp_path)], "pairs.dagger_rounds must be >= 1, got 0")


def test_unknown_config_field(tmp_path):
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\npairs: {epochz: 3}\n")
    _fails_cleanly(["pairs", "--out", str(tmp_path)], "unknown field(s) epochz")


def test_missing_run_and_missing_pistar(tmp_path):
    _fails_cleanly(["pairs", "--out", str(tmp_path / "none")], "no run at")
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    _fails_cleanly(["pairs", "--out", str(tmp_path)], "pi* not found")


def test_video_checks_its_methods_and_the_run_before_any_rollout(tmp_path):
    _fails_cleanly(["video", "--out", str(tmp_path / "none"), "--seed", "5000"], "no run at")
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    _fails_cleanly(
        ["video", "--out", str(tmp_path), "--seed", "5000", "--methods", "bc,magic"],
        "--methods has magic",
        "expected some of expert, bc, dagger",
    )
    _fails_cleanly(
        ["video", "--out", str(tmp_path), "--seed", "5000", "--fps", "0"],
        "--fps, --scale and --gif-stride must be >= 1",
    )
    _fails_cleanly(["video", "--out", str(tmp_path), "--seed", "5000", "--methods", "bc"], "pi* not found")


@pytest.mark.parametrize(
    "command",
    [["pairs"], ["evaluate", "--protocol", "mdm"], ["bench", "pairs", "--seeds", "1"]],
    ids=["pairs", "evaluate", "bench-pairs"],
)
def test_corrupt_checkpoint_is_a_clear_error(tmp_path, command):
    # a run folder whose pi* is garbage: the stage reports it before looking for work
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    gt = RunLayout(tmp_path).pistar
    gt.parent.mkdir()
    gt.write_bytes(b"not a safetensors file")
    _fails_cleanly([*command, "--out", str(tmp_path)], f"policy checkpoint is corrupt or not a safetensors file: {gt}")


def test_wrong_head_vector_length_is_a_user_error():
    policy = make_policy(CorridorTask(), seed=0)
    with pytest.raises(
        UserError, match=f"length {policy.head_size} = 3\\*32 \\+ 3, got .* shape \\({policy.head_size + 1},\\)"
    ):
        policy.load_head_vector(torch.zeros(policy.head_size + 1))
    with pytest.raises(UserError):
        policy.load_head_vector(np.zeros((2, policy.head_size), np.float32))


def test_unknown_mapper_kind(tmp_path):
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    _fails_cleanly(["train-mapper", "--out", str(tmp_path), "--kind", "xyz"], "unknown mapper kind")


def test_unknown_executor(tmp_path: Path):
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    gt = tmp_path / "pistar" / "policy.safetensors"
    make_policy(CorridorTask(), seed=0).save(gt)
    _fails_cleanly(["pairs", "--out", str(tmp_path), "--executor", "slurm"], "unknown executor 'slurm'")


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--workers", "0"], "workers must be a positive integer, got 0"),
        (["--workers", "-1"], "workers must be a positive integer, got -1"),
        (["--executor", "foo"], "unknown executor 'foo'; expected 'local', 'ray' or 'inline'"),
        (["--address", "auto"], "address 'auto' only applies to executor 'ray'; use --executor ray"),
    ],
    ids=["workers-0", "workers-negative", "unknown-executor", "address-without-ray"],
)
@pytest.mark.parametrize("command", ["pairs", "evaluate", "reproduce"])
def test_executor_options_are_checked_before_any_work(tmp_path, command, options, message):
    # an empty folder: reproduce would start a run there, the others would say there is none
    out = tmp_path / "run"
    _fails_cleanly([command, "--out", str(out), *options], message)
    assert not out.exists()


@pytest.mark.parametrize("scheme", ["ray://", ""], ids=["ray-client", "host-port"])
def test_an_unreachable_ray_address_is_one_line_at_once(tmp_path, closed_port, scheme):
    pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    address = f"{scheme}127.0.0.1:{closed_port}"
    start = time.monotonic()
    _fails_cleanly(
        ["pairs", "--out", str(tmp_path), "--executor", "ray", "--address", address],
        f"cannot reach a Ray cluster at '{address}'",
        "ray://HEAD:10001",
    )
    assert time.monotonic() - start < 15


def test_report_of_a_folder_without_a_run_is_an_error(tmp_path):
    _fails_cleanly(["report", "--out", str(tmp_path)], f"nothing has been run in {tmp_path} (no config.yaml there)")
    assert not (tmp_path / "report").exists()


def test_demo_overrides_are_checked(tmp_path):
    _fails_cleanly(["demo", "--epochs", "-1", "--out", str(tmp_path / "d")], "epochs must be an integer >= 1, got -1")
    _fails_cleanly(["demo", "--rounds", "-2", "--out", str(tmp_path / "d")], "dagger_rounds must be >= 1, got -2")
    assert not (tmp_path / "d").exists()


def test_out_that_is_a_file_is_an_error(tmp_path):
    existing = tmp_path / "notes.txt"
    existing.write_text("keep me")
    _fails_cleanly(["pistar", "--out", str(existing)], f"{existing} is a file, not a")
    assert existing.read_text() == "keep me"


@pytest.mark.parametrize(
    "command, work",
    [
        (["expert", "--seeds", "0"], "metadagger.evaluation.expert.evaluate_expert"),
        (["bench", "env", "--steps", "1", "--seeds", "0"], "metadagger.cli.bench_env.bench_env"),
        (["bench", "bc", "--images", "10", "--epochs", "1"], "metadagger.cli.bench.bench_bc"),
    ],
)
def test_an_output_file_that_is_a_folder_is_refused_before_any_work(tmp_path, monkeypatch, command, work):
    def started(*args, **kwargs):
        raise AssertionError(f"{work} ran before the output file was checked")

    monkeypatch.setattr(work, started)
    _fails_cleanly([*command, "--out", str(tmp_path)], f"--out {tmp_path} is a folder")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc, where no folder can be made")
def test_a_run_folder_that_cannot_be_made_is_one_line(tmp_path):
    _fails_cleanly(["pistar", "--out", "/proc/metadagger-run"], "cannot create folder /proc/metadagger-run")


def test_a_corrupt_json_artifact_is_named(tmp_path):
    init_run(tmp_path, "carracing", "ci")
    layout = RunLayout(tmp_path)
    layout.pairs_summary.parent.mkdir(parents=True)
    layout.pairs_summary.write_text("{x")
    _fails_cleanly(["report", "--out", str(tmp_path)], "the pairs summary is corrupt", str(layout.pairs_summary))


def test_a_table_without_its_columns_is_named(tmp_path):
    init_run(tmp_path, "carracing", "ci")
    table = RunLayout(tmp_path).eval_table("mdm")
    table.parent.mkdir(parents=True)
    table.write_text("garbage\n")
    _fails_cleanly(
        ["report", "--out", str(tmp_path)], f"the table is corrupt or unreadable: {table} (no column method, seed)"
    )


@pytest.mark.parametrize(
    "command",
    [
        ["evaluate", "--seeds", ""],
        ["benchmark", "--seeds", ""],
        ["export", "--content", "demos", "--format", "minari", "--name", "ns/x-v0", "--seeds", ""],
    ],
    ids=["evaluate", "benchmark", "export"],
)
def test_an_empty_seed_option_is_refused_not_read_as_the_default(tmp_path, command):
    init_run(tmp_path, "carracing", "ci")
    _fails_cleanly([command[0], "--out", str(tmp_path), *command[1:]], "bad seed list ''")


def test_an_empty_benchmark_method_list_is_refused(tmp_path):
    init_run(tmp_path, "carracing", "ci")
    _fails_cleanly(["benchmark", "--out", str(tmp_path), "--methods", ""], "benchmark.methods must not be empty")


def test_demo_from_a_missing_dataset_writes_nothing(tmp_path):
    pytest.importorskip("minari")
    _fails_cleanly(
        ["demo", "--demos", "no-such/dataset-v0", "--out", str(tmp_path / "d")],
        "cannot load Minari dataset 'no-such/dataset-v0'",
    )
    assert not (tmp_path / "d").exists()


def test_evaluate_protocol_errors(tmp_path):
    _fails_cleanly(["evaluate", "--out", str(tmp_path), "--protocol", "xyz"], "unknown protocol 'xyz'", "mdm, mdi, all")
    (tmp_path / "config.yaml").write_text(VERSION + "task: carracing\n")
    _fails_cleanly(["evaluate", "--out", str(tmp_path), "--protocol", "mdi"], "has no mdi section", "--protocol mdm")


def test_reproduce_with_unknown_task_names_the_known_ones(tmp_path):
    _fails_cleanly(
        ["reproduce", "--task", "cartpole", "--out", str(tmp_path / "r")],
        "unknown task 'cartpole'",
        "carracing, carracing-echo, carracing-family, fetch, fetch-family",
    )
    assert not (tmp_path / "r" / "config.yaml").exists()


@pytest.fixture
def corridor_plugin(monkeypatch):
    """The corridor task, installed as if by a package under the name "corridor-plugin"."""
    from importlib.metadata import EntryPoint

    import metadagger.tasks as tasks

    plugin = EntryPoint(name="corridor-plugin", value="toy_task:RunCorridorTask", group=tasks.ENTRY_POINT_GROUP)
    monkeypatch.setattr(tasks, "entry_points", lambda group: [plugin] if group == tasks.ENTRY_POINT_GROUP else [])
    return "corridor-plugin"


@pytest.mark.parametrize(
    "value, needles",
    [
        (
            "toy_task:RunCorridorTsk",
            ["module toy_task has no 'RunCorridorTsk'", 'fix the entry point broken = "toy_task:RunCorridorTsk"'],
        ),
        (
            "toy_tsk:RunCorridorTask",
            ["needs a missing module (toy_tsk)", 'the entry point broken = "toy_tsk:RunCorridorTask"'],
        ),
    ],
)
def test_a_broken_entry_point_is_named_with_its_fix(monkeypatch, value, needles):
    from importlib.metadata import EntryPoint

    import metadagger.tasks as tasks

    plugin = EntryPoint(name="broken", value=value, group=tasks.ENTRY_POINT_GROUP)
    monkeypatch.setattr(tasks, "entry_points", lambda group: [plugin] if group == tasks.ENTRY_POINT_GROUP else [])
    out = _fails_cleanly(["expert", "--task", "broken", "--seeds", "0"], "task 'broken'", *needles)
    assert "metadagger[" not in out  # no extra of metadagger's installs a third-party task


def test_a_corrupt_mapper_is_named_before_any_work(tmp_path, corridor_plugin):
    presets = tmp_path / "presets.yaml"
    presets.write_text(TINY_PRESETS)
    run = tmp_path / "run"
    init_run(run, corridor_plugin, "tiny", presets)
    make_policy(RunCorridorTask(max_episode_steps=12), seed=0).save(RunLayout(run).pistar)
    mapper = RunLayout(run).mapper("dm")
    mapper.parent.mkdir(parents=True)
    mapper.write_bytes(b"not a safetensors file")
    out = _fails_cleanly(
        ["evaluate", "--out", str(run), "--protocol", "mdm", "--workers", "1"],
        "error: ",
        f"corrupt or not a safetensors file: {mapper}",
    )
    assert "WorkerError" not in out


def test_a_task_from_an_installed_package_runs_with_a_presets_file(tmp_path, corridor_plugin):
    import metadagger.tasks as tasks

    assert corridor_plugin in tasks.available_tasks()
    presets = tmp_path / "presets.yaml"
    presets.write_text(TINY_PRESETS)
    run = tmp_path / "run"
    result = runner.invoke(
        app,
        ["pistar", "--task", "corridor-plugin", "--presets", str(presets), "--preset", "tiny", "--out", str(run)],
    )
    assert result.exit_code == 0, result.output
    assert (run / "pistar" / "policy.safetensors").is_file()
    assert "max_episode_steps: 12" in (run / "config.yaml").read_text()
    _fails_cleanly(
        [
            "pistar",
            "--task",
            "corridor-plugin",
            "--presets",
            str(presets),
            "--preset",
            "huge",
            "--out",
            str(tmp_path / "r2"),
        ],
        "has no preset 'huge'",
        "tiny",
    )
    _fails_cleanly(
        ["pistar", "--task", "corridor-plugin", "--out", str(tmp_path / "r3")], "no packaged presets", "--presets"
    )


def test_a_task_whose_factory_rejects_the_run_arguments_is_a_user_error(tmp_path):
    from toy_task import CorridorTask

    from metadagger.tasks import _FACTORIES, register_task

    register_task("corridor-no-kwargs", CorridorTask)
    try:
        presets = tmp_path / "presets.yaml"
        presets.write_text(TINY_PRESETS)
        _fails_cleanly(
            [
                "pistar",
                "--task",
                "corridor-no-kwargs",
                "--presets",
                str(presets),
                "--preset",
                "tiny",
                "--out",
                str(tmp_path / "r"),
            ],
            "cannot be built with {'max_episode_steps': 12}",
        )
    finally:
        del _FACTORIES["corridor-no-kwargs"]


def test_sigterm_mid_stage_is_one_line_exit_143_and_leaves_no_temporary_files(tmp_path):
    """A SIGTERM during a stage stops the command as Ctrl-C would: workers cancelled, temporary
    files removed, a line saying what was kept, the shell's exit code for SIGTERM."""
    import signal
    import subprocess
    import sys
    import time

    run = tmp_path / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "metadagger.cli",
            "reproduce",
            "--task",
            "carracing",
            "--preset",
            "ci",
            "--out",
            str(run),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not list((run / "pairs").glob("*.safetensors")) and time.monotonic() < deadline:
        time.sleep(0.05)  # the pairs stage, its workers running
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert (
        "error: stopped by SIGTERM: finished work is kept; run the same command again to resume where it stopped"
        in err.splitlines()
    )
    assert "Traceback" not in err and "leaked" not in err and "Warning" not in err
    assert not [p for p in run.rglob("*") if ".tmp" in p.name]


@pytest.mark.parametrize("signame, exit_code, said", [("SIGTERM", 143, "SIGTERM"), ("SIGINT", 130, "Ctrl-C")])
def test_a_signal_while_the_command_line_loads_is_one_line(signame, exit_code, said):
    """The console script answers a signal from its first moment: here one arrives while its
    main module is being loaded (a stand-in that signals the process)."""
    import subprocess
    import sys

    code = (
        "import os, signal, sys, time, types\n"
        "loading = types.ModuleType('metadagger.cli.main')\n"
        f"loading.__getattr__ = lambda name: (os.kill(os.getpid(), signal.{signame}), time.sleep(30))\n"
        "sys.modules['metadagger.cli.main'] = loading\n"
        "from metadagger.cli.entry import run\n"
        "run()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == exit_code
    assert done.stderr == f"error: stopped by {said} while the command line loaded: no work had started\n"


def test_expert_builds_the_task_as_a_preset_does_and_keeps_a_record(tmp_path):
    out = tmp_path / "expert.json"
    result = runner.invoke(
        app, ["expert", "--task", "carracing-echo", "--preset", "ci", "--seeds", "3", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    record = json.loads(out.read_text())
    assert record["task_kwargs"]["max_episode_steps"] == 40 and record["task_kwargs"]["fault_rate"] > 0
    assert [(row["seed"], row["steps"]) for row in record["rows"]] == [(3, 40)]  # the preset's 40 steps
    assert record["command"] == "metadagger expert --task carracing-echo --preset ci --seeds 3"
    _fails_cleanly(["expert", "--task", "carracing-echo", "--preset", "nope", "--seeds", "0"], "unknown preset 'nope'")
    mine = tmp_path / "mine.yaml"
    mine.write_text("presets:\n  short:\n    max_episode_steps: 12\n    task_options: {fault_rate: 0.01}\n")
    short = ["expert", "--task", "carracing-echo", "--presets", str(mine), "--seeds", "2", "--out", str(out)]
    _fails_cleanly(short, "no --preset says which")
    assert runner.invoke(app, [*short, "--preset", "short"]).exit_code == 0
    record = json.loads(out.read_text())
    assert record["rows"][0]["steps"] == 12 and record["command"].endswith(f"--presets {mine} --preset short --seeds 2")
