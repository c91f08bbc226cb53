"""The results registry: a run is added only after reproduce finds it current, with a manifest of
what made it; a changed file is refused; generated blocks are written from it, and check names a
block that differs; the repository's own README and docs are current."""

from __future__ import annotations

import gzip
import itertools
import json
import os
import platform
from pathlib import Path

import pytest
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.imitation.lanes import LANE_NUMERICS
from metadagger.results import registry as registry_module
from metadagger.results import staleness as staleness_module
from metadagger.results.blocks import build, wrap_prose
from metadagger.results.registry import CanonicalRun, RegistryRun, add_run, load_registry
from metadagger.results.tables import BlockContext, glance, manifest_line, report_section, runs_table
from metadagger.utils.kernels import KERNEL_ENV, NUMERICS

REPO = Path(__file__).resolve().parents[2]
CI_RUN = CanonicalRun("carracing-ci", "carracing", "ci", shows="a test run")
runner = CliRunner()
#: The manifest of a registry run made with this code's numerics, as far as the tables read it.
CURRENT = {"machine": {"cpu": "CPU", "numerics": NUMERICS}, "lane_numerics": LANE_NUMERICS}


@pytest.fixture(scope="module")
def registry(tmp_path_factory, carracing_ci_run) -> Path:
    """A registry holding one carracing ci run, added the way the canonical runs are."""
    import shutil

    tmp = tmp_path_factory.mktemp("registry")
    run = tmp / "runs" / CI_RUN.name
    shutil.copytree(carracing_ci_run, run)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(registry_module, "CANONICAL_RUNS", (CI_RUN, *registry_module.CANONICAL_RUNS))
        add_run(run, CI_RUN.name, beside="the test suite", registry=tmp / "results", progress=False)
    return tmp / "results"


@pytest.fixture()
def canonical(monkeypatch):
    runs = (CI_RUN, *registry_module.CANONICAL_RUNS)
    monkeypatch.setattr(registry_module, "CANONICAL_RUNS", runs)
    monkeypatch.setattr(staleness_module, "CANONICAL_RUNS", runs)


def test_an_added_run_keeps_small_artifacts_and_a_manifest_of_what_made_it(registry, canonical):
    root = registry / CI_RUN.name
    manifest = json.loads((root / "manifest.json").read_text())
    assert manifest["command"] == "metadagger reproduce --task carracing --preset ci --out runs/carracing-ci"
    assert manifest["beside"] == "the test suite"
    assert set(manifest["stages"]) == {"pistar", "pairs", "mappers", "evaluate", "mdi", "benchmark"}
    assert all(stage["commits"] and stage["cpus"] for stage in manifest["stages"].values())
    assert manifest["machine"]["kernels"] == (
        KERNEL_ENV if platform.machine().lower() in ("x86_64", "amd64") else "native"
    )
    assert manifest["wall_seconds"] > 0
    assert {"config.yaml", "eval/mdm.csv", "benchmark/summary.json", "report/report.md"} <= set(manifest["files"])
    # the query ledger is kept gzipped, whole
    ledger = gzip.decompress((root / "benchmark" / "labels.jsonl.gz").read_bytes())
    assert ledger and "benchmark/labels.jsonl" not in manifest["files"] and ledger.count(b"\n") > 10
    assert not list(root.rglob("*.safetensors")) and not (root / "pairs" / "pairs.jsonl").exists()
    assert set(load_registry(registry, [CI_RUN.name])) == {CI_RUN.name}


@pytest.mark.slow  # over 20 s: with the others it took the suite past 10 minutes
def test_a_run_the_docs_read_diagnostics_of_is_added_with_them(carracing_ci_run, tmp_path, monkeypatch):
    import shutil

    diagnosed = CanonicalRun("carracing-ci-diagnosed", "carracing", "ci", shows="a test run", diagnose=True)
    monkeypatch.setattr(registry_module, "CANONICAL_RUNS", (diagnosed,))
    run = tmp_path / "runs" / diagnosed.name
    shutil.copytree(carracing_ci_run, run)
    root = add_run(run, diagnosed.name, beside="the test suite", registry=tmp_path / "results", progress=False)
    manifest = json.loads((root / "manifest.json").read_text())
    assert (
        manifest["command"]
        == "metadagger reproduce --task carracing --preset ci --out runs/carracing-ci-diagnosed --diagnose"
    )
    assert "diagnose" in manifest["stages"] and "diagnostics/mapping.json" in manifest["files"]
    context = BlockContext(load_registry(tmp_path / "results", [diagnosed.name]), tmp_path)
    assert "minus mean-DA's (95%)" in report_section(context, diagnosed.name, "Does a mapper learn anything?")


def test_a_report_block_with_rows_keeps_the_tables_header_and_those_rows_only(registry, canonical, tmp_path):
    context = BlockContext(load_registry(registry, [CI_RUN.name]), tmp_path)
    heading = "Success against expert queries"
    whole = report_section(context, CI_RUN.name, heading)
    lines = whole.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    table = list(itertools.takewhile(lambda line: line.startswith("|"), lines[first:]))  # the section's first table
    picked = report_section(context, CI_RUN.name, heading, "DAgger | 1", "BC").splitlines()
    assert picked[0] == table[0]
    assert picked[2:] == [line for line in table if line.startswith("| BC |") or line.startswith("| DAgger | 1 |")]
    assert report_section(context, CI_RUN.name, heading, "BC", "columns=0,2").splitlines()[0] == (
        "| method | success (95% Wilson interval) |"
    )
    with pytest.raises(ValueError, match="has no row 'DAgger | 99'"):
        report_section(context, CI_RUN.name, heading, "DAgger | 99")


def test_a_changed_registry_file_is_refused(registry, canonical, tmp_path):
    import shutil

    copy = tmp_path / "results"
    shutil.copytree(registry, copy)
    (copy / CI_RUN.name / "eval" / "mdm.csv").write_text("method,seed\n")
    with pytest.raises(UserError, match="mdm.csv is changed since the run was added"):
        load_registry(copy, [CI_RUN.name])


def test_a_run_of_another_preset_or_name_is_refused(registry, canonical, tmp_path):
    with pytest.raises(UserError, match="not a canonical run"):
        add_run(tmp_path, "carracing-nightly", beside="nothing", registry=tmp_path / "results")
    with pytest.raises(UserError, match="--beside is empty"):
        add_run(tmp_path, CI_RUN.name, beside=" ", registry=tmp_path / "results")


def test_a_run_whose_config_departs_from_its_canonical_command_is_refused(carracing_ci_run, canonical, tmp_path):
    import shutil

    from metadagger.pipeline.run_config import load_run, save_run

    run = tmp_path / "runs" / CI_RUN.name
    shutil.copytree(carracing_ci_run, run)
    save_run(run, load_run(run, ["pairs.bc.head_init=shared"]))  # as if the preset had changed since
    with pytest.raises(UserError, match=r'departs from what .* makes \(pairs.bc.head_init: "shared" -> "seed"\)'):
        add_run(run, CI_RUN.name, beside="nothing", registry=tmp_path / "results", progress=False)
    assert not (tmp_path / "results").exists()


def test_blocks_are_written_from_the_registry_and_check_names_a_stale_one(registry, canonical, tmp_path):
    (tmp_path / "docs").mkdir()
    page = tmp_path / "docs" / "page.md"
    page.write_text(
        '# Page\n\n<!-- results: report carracing-ci "Success against expert queries" -->\n<!-- /results -->\n\n'
        "<!-- results: manifest carracing-ci -->\nold text\n<!-- /results -->\n"
        "<!-- results: runs -->\n<!-- /results -->\n<!-- results: glance -->\n<!-- /results -->\n"
        '<!-- results: figure carracing-ci report/figures/mdm_vs_bc.png "MDM against BC" -->\n<!-- /results -->\n'
        "```\n<!-- results: runs -->\nan example of the syntax, left alone\n<!-- /results -->\n```\n"
    )
    written = build(tmp_path, registry=registry)
    assert len(written) == 5
    text = page.read_text()
    assert "| MDM mean-DA (control) |" in text
    figures = Path(os.path.relpath(registry / CI_RUN.name / "report" / "figures", page.parent)).as_posix()
    assert f"]({figures}/queries.png)" in text and f"]({figures}/mdm_vs_bc.png)" in text
    assert "beside it: the test suite" in text and "old text" not in text
    assert "The paper reports carracing: SAM 86.7% raw" in text and "not run yet" in text
    assert "an example of the syntax, left alone" in text
    assert build(tmp_path, registry=registry, check=True) == []

    page.write_text(text.replace("| MDM mean-DA (control) |", "| MDM mean-DA |"))
    stale = build(tmp_path, registry=registry, check=True)
    assert len(stale) == 1 and stale[0].endswith(':3 report carracing-ci "Success against expert queries"')

    result = runner.invoke(app, ["results", "check", "--root", str(tmp_path), "--results", str(registry)])
    assert result.exit_code == 1 and "differs from what build writes: " in result.output


def _entry(method: str, setting: str, successes: int, queries: float) -> dict:
    return {
        "method": method,
        "setting": setting,
        "demo_fraction": 1.0,
        "successes": successes,
        "seeds": 10,
        "success_rate": successes / 10,
        "success_ci_low": 0.0,
        "success_ci_high": 1.0,
        "mean_queries": queries,
    }


def test_glance_puts_dagger_mdi_with_the_mappers_and_only_gated_dagger_among_the_gates(tmp_path):
    run = tmp_path / "fetch-quick"
    (run / "benchmark").mkdir(parents=True)
    entries = [
        _entry("mdm-dm", "", 0, 50),
        _entry("mdm-pistar-head", "", 5, 0),
        _entry("mdm-mean-da", "", 1, 0),
        _entry("dagger", "3", 4, 182),
        _entry("dart", "2", 3, 120),
        _entry("dart", "3", 5, 182),
        _entry("dagger-thrifty", "0.025", 6, 55),
        _entry("dagger-mdi", "two-shot", 8, 60),
        _entry("dagger-xavier", "two-shot", 9, 61),
        _entry("dagger-bc-init", "two-shot", 9, 70),
    ]
    (run / "benchmark" / "summary.json").write_text(json.dumps({"entries": entries}))
    metal, queries = _glance_rows(glance(BlockContext({"fetch-quick": RegistryRun(run, CURRENT)}, tmp_path)))
    assert metal[2] == "DAgger-MDI two-shot: 8/10 (0-100%) at 60"
    assert metal[5] == "-"  # no bc-refit row
    assert queries[2] == "5/10 (0-100%) at 182"  # DART after DAgger's last round, at its labels
    assert queries[3] == "DAgger, ThriftyDAgger gate 0.025: 6/10 (0-100%) at 55"


def _glance_rows(text: str) -> list[list[str]]:
    """The cells of a run's rows in the glance's two tables (the run's, as the only run given)."""
    rows = [line for line in text.splitlines() if line.startswith("| `") and "not run yet" not in line]
    return [[c.strip() for c in row.strip("|").split("|")] for row in rows]


def test_glance_shows_bc_refitted_beside_the_controls(tmp_path):
    run = tmp_path / "carracing-quick"
    (run / "benchmark").mkdir(parents=True)
    entries = [_entry("mdm-dm", "", 0, 745), _entry("bc-refit", "3", 9, 745), _entry("dagger", "3", 9, 3340)]
    (run / "benchmark" / "summary.json").write_text(json.dumps({"entries": entries}))
    metal, queries = _glance_rows(glance(BlockContext({"carracing-quick": RegistryRun(run, CURRENT)}, tmp_path)))
    assert metal[5] == "9/10 (0-100%) at 745" and queries[1].startswith("9/10 (") and queries[2] == "-"


def test_the_manifest_line_shows_a_call_from_an_uncommitted_tree(tmp_path):
    stage = {"commits": ["a" * 40, "a" * 40 + "+dirty"], "cpus": ["CPU"]}
    manifest = {
        "command": "metadagger reproduce",
        "wall_seconds": 60.0,
        "beside": "nothing",
        "commit": "a" * 40 + "+dirty",
        "stages": {"pairs": stage},
        "machine": {"cpu": "CPU", "instruction_sets": ["avx2"], "kernels": "native", "cores": 2, "numerics": NUMERICS},
    }
    line = manifest_line(BlockContext({"fetch-quick": RegistryRun(tmp_path, manifest)}, tmp_path), "fetch-quick")
    assert line.endswith(
        f"Stages made by {'a' * 10}, {'a' * 10}+dirty; checked current at {'a' * 10}+dirty; now current."
    )


def test_a_stale_run_is_marked_with_what_departed_where_its_numbers_show(tmp_path):
    run = tmp_path / "carracing-quick"
    (run / "benchmark").mkdir(parents=True)
    (run / "benchmark" / "summary.json").write_text(json.dumps({"entries": [_entry("dagger", "3", 9, 3340)]}))
    runs = {"carracing-quick": RegistryRun(run, CURRENT | {"wall_seconds": 60.0})}
    why = ["benchmark.lanes: 1 -> 8", f"NUMERICS {NUMERICS - 1} -> {NUMERICS}"]
    context = BlockContext(runs, tmp_path, stale={"carracing-quick": why})
    marked = (
        f"*Stale `carracing-quick` (run's -> today's): benchmark.lanes: 1 -> 8; NUMERICS {NUMERICS - 1} -> {NUMERICS}.*"
    )
    assert any(line.startswith("| `carracing-quick` (stale) |") for line in glance(context).splitlines())
    note = "*(stale): made by a config or numerics other than today's; the runs table in docs/results.md and "
    assert glance(context).endswith(note + "`metadagger results status` say what departed.*")
    (run / "report").mkdir()
    (run / "report" / "report.md").write_text("# Run\n\n## Table 1\n\n| a |\n|---|\n| 1 |\n")
    assert report_section(context, "carracing-quick", "Table 1").endswith(marked)
    assert report_section(BlockContext(runs, tmp_path), "carracing-quick", "Table 1").endswith("| 1 |")
    row = next(line for line in runs_table(context).splitlines() if line.startswith("| `carracing-quick`"))
    assert f"| stale: benchmark.lanes: 1 -> 8; NUMERICS {NUMERICS - 1} -> {NUMERICS} |" in row
    current = BlockContext(runs, tmp_path)
    assert "| current |" in next(
        line for line in runs_table(current).splitlines() if line.startswith("| `carracing-quick`")
    )
    assert "Stale" not in glance(current) and "(stale)" not in glance(current)


def test_an_unknown_block_kind_is_one_line(registry, tmp_path):
    (tmp_path / "README.md").write_text("<!-- results: tabel -->\n<!-- /results -->\n")
    result = runner.invoke(app, ["results", "build", "--root", str(tmp_path), "--results", str(registry)])
    assert result.exit_code == 2
    assert (
        result.output.strip().splitlines()[-1].startswith("error: ")
        and "block kind 'tabel' is unknown" in result.output
    )


def test_the_repositorys_readme_and_docs_are_what_build_writes():
    assert build(REPO, check=True) == [], "run `metadagger results build` and commit the result"


def test_generated_prose_is_wrapped_and_tables_headings_and_code_are_not():
    item = "- " + "word " * 30
    table = "| " + "cell | " * 40
    text = "\n".join(["prose " * 30, item, table, "# " + "heading " * 20, "```", "code " * 30, "```"])
    lines = wrap_prose(text, width=60).splitlines()
    assert all(len(line) <= 60 for line in lines if not line.startswith(("|", "#", "code")))
    assert table in lines and "# " + "heading " * 20 in lines and "code " * 30 in lines
    continued = lines[lines.index(next(line for line in lines if line.startswith("- "))) + 1]
    assert continued.startswith("  word")


def _with_lanes(task: str, preset: str, width: int):
    """``load_preset`` as it is, but with ``benchmark.lanes: width`` in ``task``'s ``preset``."""
    from metadagger.pipeline import run_config

    original = run_config.load_preset

    def load_preset(t, p, presets_file=None):
        data = original(t, p, presets_file)
        if (t, p) == (task, preset):
            data = {**data, "benchmark": {**data.get("benchmark", {}), "lanes": width}}
        return data

    return load_preset


def test_a_changed_preset_marks_exactly_the_runs_whose_canonical_command_it_changes(monkeypatch, tmp_path):
    import shutil

    from metadagger.pipeline import run_config
    from metadagger.results.staleness import registry_staleness

    runs = load_registry(REPO / "results")
    before = registry_staleness(runs)
    monkeypatch.setattr(run_config, "load_preset", _with_lanes("carracing-family", "paper", 7))
    after = registry_staleness(runs)
    changed = {name for name in runs if after[name] != before[name]}
    family_paper = {"carracing-family-paper", "carracing-family-paper-per-seed-init"}
    assert changed == family_paper & set(runs)
    for name in changed:
        new = [r for r in after[name] if r not in before[name]]
        assert len(new) == 1 and new[0].startswith("benchmark.lanes: ") and new[0].endswith(" -> 7")

    # A current run whose preset changes is marked in every block that shows its numbers, and no
    # other block changes (the docs as they are hold what build writes:
    # test_the_repositorys_readme_and_docs_are_what_build_writes).
    current = [run for run in registry_module.CANONICAL_RUNS if run.name in runs and not before[run.name]]
    if not current:
        return  # no current run in the registry to mark
    target = current[0]
    monkeypatch.setattr(run_config, "load_preset", _with_lanes(target.task, target.preset, 7))
    marked = {name for name, reasons in registry_staleness(runs).items() if reasons != before[name]}
    (tmp_path / "docs").mkdir()
    pages = [tmp_path / "README.md", tmp_path / "docs" / "results.md"]
    for page in pages:
        shutil.copy(REPO / page.relative_to(tmp_path), page)
    shutil.copytree(REPO / "results", tmp_path / "results")
    differing = build(tmp_path, check=True, files=pages)
    assert {block.split(" ")[1] for block in differing} >= {"runs"}
    every_run = [block for block in differing if len(block.split(" ")) == 2]  # a block naming no run shows them all
    assert all(any(name in block for name in marked) or block in every_run for block in differing)
    build(tmp_path, files=pages[1:])
    row = next(line for line in pages[1].read_text().splitlines() if line.startswith(f"| `{target.name}` |"))
    assert "| stale: benchmark.lanes: " in row and " -> 7 |" in row


def test_status_lists_every_canonical_run_and_strict_check_fails_on_a_stale_one(registry, canonical, tmp_path):
    import shutil

    copy = tmp_path / "results"
    shutil.copytree(registry, copy)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "page.md").write_text(f"<!-- results: manifest {CI_RUN.name} -->\n<!-- /results -->\n")
    build(tmp_path, registry=copy)
    options = ["--root", str(tmp_path), "--results", "results"]
    assert runner.invoke(app, ["results", "check", "--strict", *options]).exit_code == 0

    manifest = json.loads((copy / CI_RUN.name / "manifest.json").read_text())
    manifest["machine"]["numerics"] = NUMERICS - 1  # as if made before this code's numerics
    (copy / CI_RUN.name / "manifest.json").write_text(json.dumps(manifest))
    status = runner.invoke(app, ["results", "status", *options])
    assert status.exit_code == 0
    lines = status.output.splitlines()
    assert lines[0].startswith(f"{CI_RUN.name}: stale, last took ")
    assert lines[1].strip() == f"NUMERICS {NUMERICS - 1} -> {NUMERICS}"
    assert lines[2].strip() == f"make it: {CI_RUN.command}"
    assert f"{registry_module.CANONICAL_RUNS[1].name}: missing, last took never made" in status.output
    assert lines[-1] == f"0 current, 1 stale, {len(registry_module.CANONICAL_RUNS) - 1} missing"

    check = runner.invoke(app, ["results", "check", *options])
    assert check.exit_code == 1 and "differs from what build writes" in check.output  # its manifest line marks it now
    build(tmp_path, registry=copy)
    page = " ".join((tmp_path / "docs" / "page.md").read_text().split())  # the block's prose is wrapped
    assert f"now stale: NUMERICS {NUMERICS - 1} -> {NUMERICS}." in page
    assert runner.invoke(app, ["results", "check", *options]).exit_code == 0  # stale runs pass, marked
    strict = runner.invoke(app, ["results", "check", "--strict", *options])
    assert (
        strict.exit_code == 1 and f"stale run: {CI_RUN.name} (NUMERICS {NUMERICS - 1} -> {NUMERICS})" in strict.output
    )


def test_status_says_where_a_run_took_its_pistar_from(registry, canonical, tmp_path):
    import shutil

    copy = tmp_path / "results"
    shutil.copytree(registry, copy)
    origin = {"run": "/machine/runs/carracing-family-ci", "seconds": 7200.0, "commits": ["abc1234"], "cpus": ["CPU"]}
    (copy / CI_RUN.name / "pistar" / "origin.json").write_text(json.dumps(origin))
    status = runner.invoke(app, ["results", "status", "--root", str(tmp_path), "--results", "results"])
    first = status.output.splitlines()[0]
    assert first.startswith(f"{CI_RUN.name}: current, last took ")
    assert first.endswith("(pi* taken from the cache, made in 2 h 00 min by run carracing-family-ci)")


def test_adding_one_run_leaves_the_other_registry_runs_as_they_are(
    registry, canonical, carracing_ci_run, tmp_path, monkeypatch
):
    import shutil

    other = CanonicalRun("carracing-ci-other", "carracing", "ci", shows="a second test run")
    monkeypatch.setattr(registry_module, "CANONICAL_RUNS", (*registry_module.CANONICAL_RUNS, other))
    copy = tmp_path / "results"
    shutil.copytree(registry, copy)
    manifest = json.loads((copy / CI_RUN.name / "manifest.json").read_text())
    manifest["machine"]["numerics"] = NUMERICS - 1  # a stale run stays as it is
    (copy / CI_RUN.name / "manifest.json").write_text(json.dumps(manifest))
    before = {p: p.read_bytes() for p in (copy / CI_RUN.name).rglob("*") if p.is_file()}
    run = tmp_path / "runs" / other.name
    shutil.copytree(carracing_ci_run, run)
    add_run(run, other.name, beside="the test suite", registry=copy, progress=False)
    assert {p: p.read_bytes() for p in (copy / CI_RUN.name).rglob("*") if p.is_file()} == before
    assert set(load_registry(copy, [CI_RUN.name, other.name])) == {CI_RUN.name, other.name}
    assert json.loads((copy / other.name / "manifest.json").read_text())["machine"]["numerics"] == NUMERICS


def test_the_queries_figure_is_drawn_from_a_registry_summary_by_build_not_by_check(registry, canonical, tmp_path):
    (tmp_path / "docs").mkdir()
    page = tmp_path / "README.md"
    page.write_text(
        '<!-- results: queries-figure carracing-ci "success against expert queries" -->\n<!-- /results -->\n'
    )
    drawn = tmp_path / "docs" / "figures" / "carracing-ci-queries.png"
    assert build(tmp_path, registry=registry, check=True) != [] and not drawn.exists()  # check writes nothing
    build(tmp_path, registry=registry)
    assert drawn.read_bytes()[:4] == b"\x89PNG"
    assert "](docs/figures/carracing-ci-queries.png)" in page.read_text()
    assert build(tmp_path, registry=registry, check=True) == []


def test_a_config_of_an_older_shape_departs_by_its_sections_and_a_setting_added_since_at_its_default_does_not(
    tmp_path,
):
    import yaml

    from metadagger.pipeline.run_config import RunConfig, resolve_config
    from metadagger.results.staleness import run_staleness
    from metadagger.utils.yaml_config import dump_yaml

    data = yaml.safe_load(dump_yaml(resolve_config("carracing", "quick")))
    section = next(key for key, value in data.items() if isinstance(value, dict) and key != "pairs")
    data["old_" + section] = data.pop(section)  # a section renamed since the run was made
    defaults = yaml.safe_load(dump_yaml(RunConfig()))["pairs"]
    data["pairs"].pop(next(k for k, v in data["pairs"].items() if defaults[k] == v))  # added since, at its default
    run = tmp_path / "carracing-quick"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(data))
    reasons = run_staleness(RegistryRun(run, CURRENT))
    assert reasons == [
        f"old_{section}: a section no longer read",
        f"{section}: a section new since",
    ]


def test_a_key_renamed_since_the_run_was_made_departs_from_nothing_but_its_value_still_does(tmp_path):
    import yaml

    from metadagger.pipeline.run_config import resolve_config
    from metadagger.results.staleness import run_staleness
    from metadagger.utils.yaml_config import dump_yaml

    data = yaml.safe_load(dump_yaml(resolve_config("carracing", "quick")))
    data["benchmark"]["ceiling"] = data["benchmark"].pop("oracle")  # its name before the rename
    data["groundtruth"] = data.pop("pistar")
    run = tmp_path / "carracing-quick"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(data))
    assert run_staleness(RegistryRun(run, CURRENT)) == []
    data["benchmark"]["ceiling"] = False  # the preset runs the oracle rule
    (run / "config.yaml").write_text(yaml.safe_dump(data))
    assert run_staleness(RegistryRun(run, CURRENT)) == ["benchmark.oracle: false -> true"]
