"""Stages over one run folder, from the command line: widening what is evaluated, --set
overrides, and inputs that changed under a finished run (nothing stale is reused)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.evaluation.rows import read_csv
from metadagger.runfolder.layout import RunLayout

runner = CliRunner()


def _ok(args: list[str]) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def _refused(args: list[str], *needles: str) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def finished(carracing_ci_run) -> Path:
    """A finished CarRacing ci run (pi*, 4 pairs, every mapper, 2 evaluation seeds, report)."""
    return carracing_ci_run


def test_the_pairs_command_warns_when_dagger_barely_moved_the_heads(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    result = runner.invoke(app, ["pairs", "--out", str(layout.root)])
    assert result.exit_code == 0, result.output
    assert "warning: DAgger moved the heads by a median" in result.output  # the ci preset's fits barely move them


def _copy(run: Path, to: Path) -> RunLayout:
    shutil.copytree(run, to)
    return RunLayout(to)


def test_widening_methods_from_the_command_line_fills_every_seed(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    shutil.rmtree(layout.eval_dir)
    _ok(["evaluate", "--out", layout.root, "--seeds", "5000", "--set", "evaluate.methods=[pistar-head]"])
    _ok(["evaluate", "--out", layout.root, "--seeds", "5000-5001", "--set", "evaluate.methods=[pistar-head, dm]"])
    rows = read_csv(layout.eval_table("mdm"))
    assert sorted((r["method"], r["seed"]) for r in rows) == sorted(
        (m, s) for m in ("bc", "pistar-head", "dm") for s in (5000, 5001)
    )
    # and they are the rows the full run made
    reference = {(r["method"], r["seed"]): r for r in read_csv(RunLayout(finished).eval_table("mdm"))}
    assert all(r == reference[r["method"], r["seed"]] for r in rows)
    assert "  - pistar-head\n  - dm\n" in layout.config.read_text()  # the config the command ran with


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_train_mapper_on_incomplete_pairs_refuses_and_reproduce_rebuilds(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    lines = (layout.pairs_dir / "pairs.jsonl").read_bytes().splitlines(keepends=True)
    (layout.pairs_dir / "pairs.jsonl").write_bytes(b"".join(lines[:-1]))
    for folder in (layout.root / "mappers", layout.eval_dir, layout.report_dir):
        shutil.rmtree(folder)
    _refused(
        ["train-mapper", "--out", layout.root, "--kind", "all"],
        "1 of 4 seeds of pairs.seeds have no current pair",
        "metadagger pairs",
    )
    _refused(["evaluate", "--out", layout.root], "mapper dm not trained yet")
    _ok(["reproduce", "--task", "carracing", "--preset", "ci", "--out", layout.root])
    # the refilled pair is the same, so the rebuilt mappers and tables are the reference run's
    assert layout.eval_table("mdm").read_bytes() == RunLayout(finished).eval_table("mdm").read_bytes()
    assert layout.mapper("sam").read_bytes() == RunLayout(finished).mapper("sam").read_bytes()


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_changed_settings_are_named_by_a_stage_and_rebuilt_by_reproduce(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    before = {kind: layout.mapper(kind).read_bytes() for kind in ("dm", "mean-da")}
    config = layout.config.read_bytes()
    _refused(["pairs", "--out", layout.root, "--set", "pairs.dagger_rounds=2"], "dagger_rounds: 1 -> 2", "--rebuild")
    assert layout.config.read_bytes() == config  # a refused command leaves the run's config as it was
    # a later option, left out of the stamps at its default
    _refused(
        ["pairs", "--out", layout.root, "--set", "pairs.bc.head_init=shared"], 'bc.head_init: (default) -> "shared"'
    )
    _refused(
        ["train-mapper", "--out", layout.root, "--kind", "dm", "--set", "pairs.dagger_rounds=2"],
        "no current pair",
        "dagger_rounds: 1 -> 2",
    )
    _ok(["reproduce", "--task", "carracing", "--preset", "ci", "--out", layout.root, "--set", "pairs.dagger_rounds=2"])
    assert "  dagger_rounds: 2\n" in layout.config.read_text()  # the config reproduce ran with
    records = (layout.pairs_dir / "pairs.jsonl").read_text()
    assert records.count('"dagger_rounds":2') == 4  # every pair made again with two rounds
    assert layout.mapper("dm").read_bytes() != before["dm"]  # trained on the new pairs
    assert layout.mapper("mean-da").read_bytes() != before["mean-da"]
    # and the evaluation was redone with the new mappers: every row matches their stamps
    log = (layout.eval_dir / "rows.jsonl").read_text()
    assert len(read_csv(layout.eval_table("mdm"))) == 2 * 7 and log.count("\n") > 2  # bc + 6 kinds on 2 seeds


def test_pistar_with_another_config_is_refused(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    _refused(
        [
            "pistar",
            "--task",
            "carracing",
            "--preset",
            "ci",
            "--out",
            layout.root,
            "--set",
            "pistar.bc.epochs=2",
        ],
        "pi* in",
        "bc.epochs: 1 -> 2",
    )


def test_config_show_prints_the_resolved_config():
    out = _ok(
        [
            "config",
            "show",
            "--task",
            "fetch",
            "--preset",
            "ci",
            "--set",
            "pairs.dagger_rounds=3",
            "--set",
            "evaluate.methods=[dm, sam]",
        ]
    )
    assert "task: fetch\npreset: ci\n" in out and "  dagger_rounds: 3\n" in out and "  - dm\n  - sam\n" in out


@pytest.mark.parametrize(
    ("override", "needle"),
    [
        ("pairs.dagger_rounds", "bad --set 'pairs.dagger_rounds': expected section.key=value"),
        ("pairs.epochz=3", "unknown field(s) epochz"),
        ("pairs.dagger_rounds=0", "pairs.dagger_rounds must be >= 1, got 0"),
        ("evaluate.methods=[dm, xyz]", "unknown method(s) ['xyz']"),
        ("mappers.dm.lr=-1", "MapperConfig.lr must be > 0"),
        ("evaluate.methods=[dm", "not YAML"),
    ],
)
def test_bad_overrides_are_one_line(override, needle):
    _refused(["config", "show", "--task", "carracing", "--preset", "ci", "--set", override], needle)


def test_diagnose_reproduces_each_validation_pair_resumes_and_reports(finished, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    layout = RunLayout(run)
    _ok(["diagnose", "--out", run, "--workers", "1"])
    summary = json.loads(layout.diagnostics_summary.read_text())
    assert set(summary["methods"]) == {"bc", "dm", "sam", "tam", "ridge", "mean-da", "pistar-head"}
    for name, errors in summary["methods"].items():
        assert 0.0 <= errors["function"]["mean"] <= 1.0 and errors["weight"]["mean"] >= 0.0
        if name == "bc":
            assert "function_minus_bc" not in errors
        else:  # paired over the same validation pairs, so the means subtract
            difference = errors["function_minus_bc"]
            assert difference["mean"] == pytest.approx(
                errors["function"]["mean"] - summary["methods"]["bc"]["function"]["mean"]
            )
            assert difference["n"] == summary["val_pairs"]
            assert (
                math.isnan(difference["low"])
                if difference["n"] == 1
                else difference["low"] <= difference["mean"] <= difference["high"]
            )
        for control in ("mean-da", "pistar-head"):  # paired against each control, never against itself
            if name in ("bc", control):
                assert f"function_minus_{control}" not in errors
            else:
                difference = errors[f"function_minus_{control}"]
                assert difference["n"] == summary["val_pairs"]
                assert difference["mean"] == pytest.approx(
                    errors["function"]["mean"] - summary["methods"][control]["function"]["mean"]
                )
    assert summary["noise_ceiling"]["heads_per_seed"] == 3 and summary["noise_ceiling"]["function"] is not None
    assert {r["kind"] for r in summary["scaling"]} == {"dm", "sam", "tam", "ridge"}
    for row in summary["scaling"]:  # the 100% point is the run's own mapper, not fitted again
        full = row["fraction"] == 1.0
        assert (
            (row["function"] == summary["methods"][row["kind"]]["function"]["mean"])
            if full
            else row["train_pairs"] < summary["train_pairs"]
        )
        assert row["function_minus_bc"]["mean"] == pytest.approx(
            row["function"] - summary["methods"]["bc"]["function"]["mean"]
        )
        assert layout.diagnostics_scaling(row["kind"], row["fraction"]).exists() != full
    log = [json.loads(line) for line in layout.diagnostics_log.read_text().splitlines()]
    assert all(row["reproduced"] for line in log for row in line["entries"].get("states", {}).get("rows", []))
    before = layout.diagnostics_log.read_bytes()
    _ok(["diagnose", "--out", run, "--workers", "1"])  # nothing left to re-run
    assert layout.diagnostics_log.read_bytes() == before
    _ok(["report", "--out", run])
    report = layout.report.read_text()
    assert "## Does a mapper learn anything?" in report and "minus w_BC's (95%)" in report
    assert "minus mean-DA's (95%)" in report and "minus pi*-head's (95%)" in report
    nearer = [
        k
        for k in ("dm", "sam", "tam", "ridge")
        if all(summary["methods"][k][f"function_minus_{c}"]["high"] < 0 for c in ("mean-da", "pistar-head"))
    ]
    assert ("No learned mapper is nearer to w_DA in actions than mean-DA and pi*-head" in report) == (not nearer)


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_reproduce_runs_the_diagnostics_only_when_asked(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    before = {
        path: path.read_bytes()
        for path in (layout.eval_table("mdm"), layout.mapper("sam"), layout.pairs_dir / "pairs.jsonl")
    }
    _ok(["reproduce", "--task", "carracing", "--preset", "ci", "--out", layout.root])
    assert not layout.diagnostics_summary.exists()
    _ok(["reproduce", "--task", "carracing", "--preset", "ci", "--out", layout.root, "--diagnose"])
    summary = json.loads(layout.diagnostics_summary.read_text())
    assert summary["val_pairs"] >= 1 and "function_minus_mean-da" in summary["methods"]["dm"]
    assert "## Does a mapper learn anything?" in layout.report.read_text()
    assert all(path.read_bytes() == data for path, data in before.items())  # nothing before the diagnostics ran again


def test_diagnose_refuses_bad_settings_in_one_line(finished):
    _refused(["diagnose", "--out", finished, "--set", "diagnose.scaling=[0, 1]"], "diagnose.scaling")


def test_a_damaged_pair_file_is_named_by_train_mapper_and_collected_again_by_pairs(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    pair = sorted(layout.pairs_dir.glob("*.safetensors"))[0]
    pair.write_bytes(pair.read_bytes()[:100])
    _refused(
        ["train-mapper", "--out", layout.root, "--kind", "dm"],
        f"pair file {pair} is corrupt or not a safetensors file (",
        f"; run `metadagger pairs --out {layout.root}`, which collects that pair again",
    )
    _ok(["pairs", "--out", layout.root])
    assert pair.read_bytes() == (finished / "pairs" / pair.name).read_bytes()


def test_a_weak_pistar_stops_before_any_pair_and_names_its_rates(finished, tmp_path):
    """pi* below pistar.min_success on its unseen seeds: one line with its rates and what to
    try; pi* is kept (the threshold is not part of its stamp) and no pair is collected."""
    layout = _copy(finished, tmp_path / "run")
    shutil.rmtree(layout.pairs_dir)
    pistar = layout.pistar.read_bytes()
    line = _refused(
        ["pairs", "--out", layout.root, "--set", "pistar.min_success=0.5"],
        "too weak to learn from",
        "own seeds 0/2",
        "unseen seeds 0/1 (0%, 95% interval 0%-79%)",
        "pistar.min_success=0.5",
        "Making pi* work on a new task",
    )
    assert "augment_shift" in line
    assert layout.pistar.read_bytes() == pistar and not layout.pairs_dir.exists()


def test_too_few_kept_pairs_names_the_outcomes_and_pistar(finished, tmp_path):
    layout = _copy(finished, tmp_path / "run")
    _refused(
        ["train-mapper", "--out", layout.root, "--kind", "dm", "--set", "pairs.val_fraction=0.9"],
        "only 4 kept pairs (pairs.keep=all)",
        "pairs.val_fraction=0.9",
        "of 4 pair seeds: bc_ok/da_ok 0",
        "bc_fail/da_fail 4",
        "pi*: own seeds 0/2",
    )


def test_pairs_summary_records_how_far_dagger_moved_the_heads(finished):
    from metadagger.metal_dagger.pairs import NEGLIGIBLE_HEAD_CHANGE, negligible_change_warning

    summary = json.loads(RunLayout(finished).pairs_summary.read_text())
    change = summary["head_change"]
    assert 0 <= change["min"] <= change["median"] <= change["max"]
    weak = {**summary, "head_change": {"median": NEGLIGIBLE_HEAD_CHANGE / 2, "min": 0.01, "max": 0.06}}
    assert "DAgger moved the heads by a median 5.0%" in negligible_change_warning(weak)
    assert negligible_change_warning({**summary, "head_change": {"median": 1.0, "min": 0.5, "max": 2.0}}) is None


def test_the_prior_method_chooses_its_strengths_on_the_validation_pairs_and_rows_each_mean(finished, tmp_path):
    """``benchmark --methods bc,prior``: a prior toward each evaluated mapper kind and zero, its
    strength chosen on the validation pairs and written to benchmark/priors.json, one row per mean."""
    from metadagger.mapping.priors import LIMIT, STRENGTHS
    from metadagger.pipeline.run_config import load_run

    layout = _copy(finished, tmp_path / "run")
    shutil.rmtree(layout.benchmark_dir, ignore_errors=True)
    _ok(["benchmark", "--out", layout.root, "--seeds", "5000", "--methods", "bc,prior"])
    kinds = list(load_run(layout.root).evaluate.methods)
    record = json.loads(layout.benchmark_priors.read_text())
    priors = record["chosen"]
    assert set(priors) == {*kinds, "zero"}
    for choice in priors.values():
        grid = sorted(float(k) for k in choice["distances"] if k != LIMIT)  # the file's keys are sorted as text
        assert choice["strength"] in [*grid, LIMIT] and grid[: len(STRENGTHS)] == list(STRENGTHS)
        assert LIMIT in choice["distances"] and isinstance(choice["edge"], bool)
    rows = read_csv(layout.benchmark_table)
    assert {r["method"] for r in rows} >= {"bc", *(f"prior-{kind}" for kind in kinds), "prior-zero"}
    # another call (DAgger with the priors) reads the choice back instead of making it again
    made = layout.benchmark_priors.stat().st_mtime_ns
    _ok(["benchmark", "--out", layout.root, "--seeds", "5000", "--methods", "bc,dagger,prior-dagger"])
    assert layout.benchmark_priors.stat().st_mtime_ns == made
    assert {r["method"] for r in read_csv(layout.benchmark_table)} >= {f"prior-dagger-{kind}" for kind in kinds}


def test_the_confirmation_seeds_run_the_same_methods_into_their_own_folder_and_report(finished, tmp_path):
    """``benchmark.confirm_seeds``: the benchmark runs again on them into benchmark/confirm/, its
    progress named apart, the report (written again by the command) reads them at equal budgets; a
    seed of pi*'s or of both sets is refused before any work."""
    from metadagger.evaluation.report.benchmark import benchmark_section

    layout = _copy(finished, tmp_path / "run")
    layout.report.unlink()
    said = _ok(["benchmark", "--out", layout.root, "--methods", "bc,dagger", "--set", "benchmark.confirm_seeds=[5003]"])
    # the report follows the benchmark: written again at its end, its section reading the new rows
    assert f"wrote {layout.report}" in said and "At equal budgets (confirmation seeds)" in layout.report.read_text()
    # the progress says that a second set follows, and which set each line counts
    assert "benchmark: the unseen seeds (" in said and "then the confirmation seeds (1)" in said, said
    assert "benchmark, confirmation seeds: 1/1" in said, said
    confirm = layout.confirmation()
    assert {r["seed"] for r in read_csv(confirm.benchmark_table)} == {5003}
    assert {r["method"] for r in read_csv(confirm.benchmark_table)} == {"bc", "dagger", "dagger-oracle"}
    assert 5003 not in {r["seed"] for r in read_csv(layout.benchmark_table)}
    text = "\n".join(benchmark_section(layout))
    assert "### At equal budgets (confirmation seeds)" in text and "`benchmark.confirm_seeds`" in text
    _refused(["benchmark", "--out", layout.root, "--set", "benchmark.confirm_seeds=[0]"], "must be unseen")
    _refused(["benchmark", "--out", layout.root, "--set", "benchmark.confirm_seeds=[5000]"], "other seeds")
