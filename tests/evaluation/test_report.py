"""The report, built from artifacts on disk alone: one section per protocol, shared tables."""

from __future__ import annotations

import pytest

from metadagger.errors import UserError
from metadagger.evaluation.report.build import build_report
from metadagger.evaluation.report.mdm import FIGURE
from metadagger.evaluation.report.tables import markdown_table
from metadagger.evaluation.rows import write_csv
from metadagger.mapping.train import CURVE_COLUMNS
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import write_json, write_text


def _row(method: str, seed: int, success: bool, reward: float, steps: int = 100) -> dict:
    return {"method": method, "seed": seed, "success": success, "reward": reward, "steps": steps, "expert_queries": 50}


@pytest.fixture
def run(tmp_path) -> RunLayout:
    layout = RunLayout(tmp_path / "myrun")
    write_text(layout.config, "task: carracing\npreset: quick\n")
    rows = []
    for seed, (bc, dm, ctl) in enumerate([(False, True, True), (False, False, True), (True, True, True)]):
        rows += [
            _row("bc", seed, bc, 100.0 + seed),
            _row("dm", seed, dm, 500.0 + 100 * seed),
            _row("pistar-head", seed, ctl, 900.0),
        ]
    write_csv(layout.eval_table("mdm"), rows)
    write_csv(layout.eval_table("oneshot"), [_row("oneshot-dm", 1, True, 800.0)])
    write_csv(layout.mapper_curves("dm"), [_curve("dm", 1, 3.0), _curve("dm", 2, 2.0)], fields=CURVE_COLUMNS)
    write_csv(layout.mapper_curves("mean-da"), [_curve("mean-da", 0, 1.6, losses=False)], fields=CURVE_COLUMNS)
    return layout


def _curve(kind: str, epoch: int, val: float, losses: bool = True) -> dict:
    return {
        "model": kind,
        "epoch": epoch,
        "train_loss": 0.5 if losses else "",
        "val_loss": 0.6 if losses else "",
        "train_mse_weights": 0.4,
        "val_mse_weights": val,
    }


def test_sections_tables_and_figures(run):
    text = build_report(run).read_text()
    assert text.startswith("# MetaL DAgger report: carracing, preset quick (`myrun`)")
    # Table 1: raw over 3 seeds, adjusted without the seed BC solves
    assert "| DM | 66.7% (2/3; 20.8%-93.9%) | 50.0% (1/2; 9.5%-90.5%) |" in text
    # Table 2 gives the spread over seeds
    assert "| DM | 600.0 ± 100.0 | 100 ± 0 | 50 |" in text
    # one-shot: a table for the mapper that failed somewhere, a line for the control that never did
    assert "### DM: 1/1 failed seeds solved by one-shot" in text
    assert "### pi*-head (control): no failed seed to refit" in text
    # the weight-space error of each mapper beside the mean-DA control's
    assert "| DM | 0.4 | 2 | 1.25 |" in text and "| mean-DA (control) | 0.4 | 1.6 | 1.00 |" in text
    assert (run.figures / FIGURE).is_file() and (run.figures / "curves_dm.png").is_file()


def test_rebuilding_gives_the_same_report(run):
    first = build_report(run).read_text()
    assert build_report(run).read_text() == first


def test_an_empty_folder_is_no_run(tmp_path):
    with pytest.raises(UserError, match="nothing has been run in"):
        build_report(RunLayout(tmp_path))
    write_text(RunLayout(tmp_path).config, "task: carracing\npreset: quick\n")
    with pytest.raises(UserError, match="nothing to report"):
        build_report(RunLayout(tmp_path))


def test_pistar_and_pairs_sections(tmp_path):
    layout = RunLayout(tmp_path)
    write_text(layout.config, "task: fetch\npreset: ci\n")
    stats = {
        "episodes": 10,
        "successes": 8,
        "success_rate": 0.8,
        "success_ci_low": 0.49,
        "success_ci_high": 0.94,
        "mean_reward": 1.0,
        "mean_steps": 30.0,
    }
    write_json(layout.pistar_metrics, {"own_seeds": stats, "unseen_seeds": stats, "expert_queries": 1234})
    names = ("bc_ok/da_ok", "bc_ok/da_fail", "bc_fail/da_ok", "bc_fail/da_fail")
    write_json(
        layout.pairs_summary,
        {
            "seeds": 4,
            "kept": 2,
            "outcomes": dict(zip(names, (1, 1, 2, 0))),
            "shares": dict(zip(names, (0.25, 0.25, 0.5, 0.0))),
        },
    )
    text = build_report(layout).read_text()
    assert (
        "| unseen seeds | 8/10 | 80.0% | 49.0%-94.0% | 1.0 | 30 |" in text
        and "Expert queries spent on pi*: 1234." in text
    )
    assert "4 seeds, 2 pairs kept." in text and "| bc fail, da ok | 2 | 50.0% |" in text


def test_a_kind_with_a_context_reports_its_unlabelled_rollout(run):
    rows = [
        _row("bc", 0, False, 100.0),
        {**_row("conditioned", 0, True, 900.0), "unlabelled_steps": 300},
        _row("bc", 1, False, 100.0),
        {**_row("conditioned", 1, False, 200.0), "unlabelled_steps": 500},
    ]
    write_csv(run.eval_table("mdm"), rows, fields=tuple(rows[1]))
    text = build_report(run).read_text()
    assert (
        "Conditioned also read the seed's context: one rollout of the BC head, never labelled, 400 env steps per seed"
        in text
    )
    assert "BC also read" not in text


def test_a_closed_form_kind_and_a_control_have_no_curve(run):
    write_csv(run.mapper_curves("ridge"), [_curve("ridge", 0, 1.8)], fields=CURVE_COLUMNS)
    write_csv(run.mapper_curves("pistar-head"), [_curve("pistar-head", 0, 2.4, losses=False)], fields=CURVE_COLUMNS)
    text = build_report(run).read_text()
    assert "![DM learning curves](figures/curves_dm.png)" in text and (run.figures / "curves_dm.png").is_file()
    assert (
        "Ridge is fitted in closed form; mean-DA (control), pi*-head (control) are constants: one point each, so no "
        "learning curve (their errors are in the table above)."
    ) in text
    assert not any((run.figures / f"curves_{kind}.png").exists() for kind in ("ridge", "mean-da", "pistar-head"))


def test_a_single_point_is_a_note_not_a_dot(run, tmp_path, monkeypatch):
    from matplotlib.axes import Axes

    from metadagger.evaluation.curves import plot_curves

    drawn, notes = [], []
    plot, text = Axes.plot, Axes.text
    monkeypatch.setattr(Axes, "plot", lambda self, *a, **k: drawn.append(self.get_title()) or plot(self, *a, **k))
    monkeypatch.setattr(
        Axes, "text", lambda self, x, y, s, **k: notes.append((self.get_title(), s)) or text(self, x, y, s, **k)
    )
    write_csv(tmp_path / "ridge.csv", [_curve("ridge", 0, 1.8)], fields=CURVE_COLUMNS)
    assert plot_curves(tmp_path / "ridge.csv", tmp_path / "ridge.png").read_bytes()[:4] == b"\x89PNG"
    assert drawn == []
    assert notes == [
        ("ridge: one point, no curve", "MSE (standardised): train 0.5, validation 0.6"),
        ("whole mapping f: one point, no curve", "MSE (weight units): train 0.4, validation 1.8"),
    ]
    plot_curves(run.mapper_curves("dm"), tmp_path / "dm.png")  # two epochs: curves
    assert drawn == ["dm", "dm", "whole mapping f", "whole mapping f"]


def _split_run(tmp_path, kept: int) -> RunLayout:
    layout = RunLayout(tmp_path)
    write_text(layout.config, "task: carracing\npreset: quick\npairs:\n  val_fraction: 0.25\nsplit_seed: 7\n")
    names = ("bc_ok/da_ok", "bc_ok/da_fail", "bc_fail/da_ok", "bc_fail/da_fail")
    write_json(
        layout.pairs_summary,
        {
            "seeds": 10,
            "kept": kept,
            "outcomes": dict(zip(names, (0, 0, kept, 10 - kept))),
            "shares": dict(zip(names, (0.0, 0.0, kept / 10, 1 - kept / 10))),
        },
    )
    return layout


def test_the_pairs_section_states_the_train_validation_split(tmp_path):
    text = build_report(_split_run(tmp_path / "a", kept=10)).read_text()
    assert (
        "Train/validation split: the mappers train on 7 of the 10 kept pairs and validate on 3 "
        "(pairs.val_fraction 0.25, split_seed 7: a seeded permutation of the kept seeds)."
    ) in text
    text = build_report(_split_run(tmp_path / "b", kept=1)).read_text()
    assert (
        "Train/validation split: 1 kept pairs are too few for a training set (pairs.val_fraction 0.25, split_seed 7)."
        in text
    )


def test_stage_wall_times_are_a_table_in_the_run_section(run):
    assert "## Run" not in build_report(run).read_text()  # no file: nothing shown
    write_json(
        run.stage_times,
        {
            "benchmark": {"seconds": 4000.0, "finished": "2025-01-01T11:08:00+00:00"},
            "pistar": {"seconds": 12.34, "finished": "2025-01-01T10:00:00+00:00"},
            "pairs": {"seconds": 75.2, "finished": "2025-01-01T10:01:15+00:00"},
        },
    )
    text = build_report(run).read_text()
    assert text.index("## Run") < text.index("## Mappers")
    assert (
        "\n".join(
            [
                "| stage | wall time | finished |",
                "|---|---|---|",
                "| pistar | 12.3 s | 2025-01-01T10:00:00+00:00 |",
                "| pairs | 1 min 15 s | 2025-01-01T10:01:15+00:00 |",
                "| benchmark | 1 h 07 min | 2025-01-01T11:08:00+00:00 |",
                "| all stages | 1 h 08 min |  |",
            ]
        )
        in text
    )
    # a stage called twice (resumed): its sum over all calls beside its last call
    write_json(
        run.stage_times, {"pairs": {"seconds": 30.0, "total_seconds": 90.0, "finished": "2025-01-01T10:01:15+00:00"}}
    )
    assert "| pairs | 30.0 s | 1 min 30 s | 2025-01-01T10:01:15+00:00 |" in build_report(run).read_text()


@pytest.mark.parametrize(
    "content, reason",
    [
        ("{not json", "Expecting property name enclosed in double quotes: line 1 column 2 (char 1)"),
        ("[1, 2]", "expected a JSON object of stages, got list"),
        (
            '{"pairs": {"seconds": "fast", "finished": "today"}}',
            "stage 'pairs': seconds must be a number of seconds, got 'fast'",
        ),
        (
            '{"pairs": {"seconds": 3.0}}',
            'stage \'pairs\': expected {"seconds": ..., "finished": "..."}, got {\'seconds\': 3.0}',
        ),
    ],
)
def test_a_malformed_stage_times_file_is_one_line(run, content, reason):
    write_text(run.stage_times, content)
    text = build_report(run).read_text()
    assert f"## Run\n\nStage wall times: `stage_times.json` could not be read ({reason}).\n\n## Mappers" in text


def test_a_figure_that_fails_costs_only_itself(run, capsys, monkeypatch):
    from metadagger.evaluation.report import mdm as report_mdm
    from metadagger.evaluation.report import run as report_run
    from metadagger.utils.plotting import plt

    def broken(*args):
        plt.subplots()
        raise RuntimeError("no ink")

    monkeypatch.setattr(report_mdm, "_scatter", broken)
    monkeypatch.setattr(report_run, "plot_curves", broken)
    text = build_report(run).read_text()
    assert "| DM | 66.7% (2/3; 20.8%-93.9%) | 50.0% (1/2; 9.5%-90.5%) |" in text  # the tables are all there
    assert (
        "### Fig. 4: each method against BC (one point per seed; filled: the method succeeded)\n\n"
        "Figure `mdm_vs_bc.png` could not be drawn (RuntimeError: no ink).\n" in text
    )
    assert "Figure `curves_dm.png` could not be drawn (RuntimeError: no ink)." in text
    assert "![MDM vs BC]" not in text and "![DM learning curves]" not in text
    assert capsys.readouterr().err.splitlines() == [
        f"warning: figure {run.figures / 'curves_dm.png'} was not drawn (RuntimeError: no ink)",
        f"warning: figure {run.figures / FIGURE} was not drawn (RuntimeError: no ink)",
    ]
    assert plt.get_fignums() == []


def test_a_table_row_with_another_number_of_cells_than_columns_is_refused():
    assert markdown_table(("a", "b"), [(1, 2)]) == ["| a | b |", "|---|---|", "| 1 | 2 |"]
    with pytest.raises(ValueError, match="a table row has 3 cells under 2 columns"):
        markdown_table(("a", "b"), [(1, 2), (1, 2, 3)])
