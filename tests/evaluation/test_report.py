"""The report, built from artifacts on disk alone: one section per protocol, shared tables."""

from __future__ import annotations

import pytest

from metadagger.errors import UserError
from metadagger.evaluation.report import build_report
from metadagger.evaluation.report_mdm import FIGURE
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
        rows += [_row("bc", seed, bc, 100.0 + seed), _row("dm", seed, dm, 500.0 + 100 * seed), _row("pistar-head", seed, ctl, 900.0)]
    write_csv(layout.eval_table("mdm"), rows)
    write_csv(layout.eval_table("oneshot"), [_row("oneshot-dm", 1, True, 800.0)])
    for kind, val in (("dm", 2.0), ("mean-da", 1.6)):
        write_csv(layout.mapper_curves(kind), [{"model": kind, "epoch": 1, "train_loss": 0.5, "val_loss": 0.6,
                                               "train_mse_weights": 0.4, "val_mse_weights": val}], fields=CURVE_COLUMNS)
    return layout


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


def test_groundtruth_and_pairs_sections(tmp_path):
    layout = RunLayout(tmp_path)
    write_text(layout.config, "task: fetch\npreset: ci\n")
    stats = {"episodes": 10, "successes": 8, "success_rate": 0.8, "success_ci_low": 0.49, "success_ci_high": 0.94,
             "mean_reward": 1.0, "mean_steps": 30.0}
    write_json(layout.groundtruth_metrics, {"own_seeds": stats, "unseen_seeds": stats, "expert_queries": 1234})
    names = ("bc_ok/da_ok", "bc_ok/da_fail", "bc_fail/da_ok", "bc_fail/da_fail")
    write_json(layout.pairs_summary, {"seeds": 4, "kept": 2, "outcomes": dict(zip(names, (1, 1, 2, 0))),
                                      "shares": dict(zip(names, (0.25, 0.25, 0.5, 0.0)))})
    text = build_report(layout).read_text()
    assert "| unseen seeds | 8/10 | 80.0% | 49.0%-94.0% | 1.0 | 30 |" in text and "Expert queries spent on pi*: 1234." in text
    assert "4 seeds, 2 pairs kept." in text and "| bc fail, da ok | 2 | 50.0% |" in text


def test_a_kind_with_a_context_reports_its_unlabelled_rollout(run):
    rows = [_row("bc", 0, False, 100.0), {**_row("conditioned", 0, True, 900.0), "unlabelled_steps": 300},
            _row("bc", 1, False, 100.0), {**_row("conditioned", 1, False, 200.0), "unlabelled_steps": 500}]
    write_csv(run.eval_table("mdm"), rows, fields=tuple(rows[1]))
    text = build_report(run).read_text()
    assert "Conditioned also read the seed's context: one rollout of the BC head, never labelled, 400 env steps per seed" in text
    assert "BC also read" not in text
