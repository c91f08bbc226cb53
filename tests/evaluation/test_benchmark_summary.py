"""The benchmark read at equal budgets and by the area under the curve, on hand-made rows."""

from __future__ import annotations

import pytest

from metadagger.evaluation.benchmark.summary import AUC_POINTS, budget_reading, refit_check, success_at_budget


def _row(method: str, setting: str, seed: int, success: bool, queries: int, fraction: float = 1.0) -> dict:
    return {
        "method": method,
        "setting": setting,
        "demo_fraction": fraction,
        "seed": seed,
        "success": success,
        "reward": float(success),
        "expert_queries": queries,
    }


def _rows() -> list[dict]:
    """Six seeds: a demonstration of 100 queries, DAgger to 500; a safe gate at 180 (every other seed) and
    120 (every seed); the mean-DA control at 0 (seeds 0, 1); the oracle at 110 (every seed)."""
    rows = []
    for seed in range(6):
        rows += [
            _row("bc", "", seed, False, 100),
            _row("dagger", "1", seed, False, 300),
            _row("dagger", "2", seed, True, 500),
            _row("dagger-safe", "0.5", seed, seed % 2 == 0, 180),
            _row("dagger-safe", "0.8", seed, True, 120),
            _row("mdm-mean-da", "", seed, seed < 2, 0),
            _row("dagger-oracle", "0", seed, True, 110),
        ]
    return rows


def test_a_method_is_read_at_its_last_row_within_the_budget_else_bc_else_a_failure():
    rows = [_row("m", "a", 0, True, 50), _row("m", "b", 0, False, 80)]
    bc = _row("bc", "", 0, True, 40)
    assert success_at_budget(rows, bc, 90)["expert_queries"] == 80  # the last within, not the best
    assert success_at_budget(rows, bc, 60)["expert_queries"] == 50
    assert success_at_budget(rows, bc, 45) is bc
    assert success_at_budget(rows, bc, 30) == {"success": False, "reward": 0.0, "expert_queries": 0}


def test_budgets_are_the_demonstration_plus_shares_of_daggers_queries_beyond_it():
    reading = budget_reading(_rows())
    assert reading["seeds"] == list(range(6))
    successes = {b["share"]: {e["method"]: e["successes"] for e in b["entries"]} for b in reading["budgets"]}
    # budgets 100 + share * 400: 120, 140, 200
    assert [b["mean_budget"] for b in reading["budgets"]] == [120.0, 140.0, 200.0]
    assert successes[0.05] == {"bc": 0, "dagger": 0, "dagger-safe": 6, "mdm-mean-da": 2, "dagger-oracle": 6}
    assert successes[0.25]["dagger-safe"] == 3  # its 180-query setting, the last within 200
    # the oracle and the control are references: neither is ranked
    assert all(b["best"] == {"method": "dagger-safe", "demo_fraction": 1.0} for b in reading["budgets"])
    against = {c["against"] for c in reading["budgets"][0]["comparisons"]}
    assert against == {"mdm-mean-da"}  # the best gate is the best method itself here


def test_the_area_under_the_curve_is_the_mean_success_over_log_spaced_budgets():
    reading = budget_reading(_rows())
    auc = {a["method"]: a for a in reading["auc"]}
    assert auc["mdm-mean-da"]["per_seed"] == [1.0, 1.0, 0.0, 0.0, 0.0, 0.0]  # zero queries: every budget
    assert auc["dagger"]["per_seed"] == [1 / AUC_POINTS] * 6  # only the last budget reaches round 2
    assert 0.0 <= auc["dagger-safe"]["mean"] <= auc["dagger-oracle"]["mean"] <= 1.0
    assert reading["best_auc"] == {"method": "dagger-safe", "demo_fraction": 1.0}
    oracle = next(c for c in reading["auc_comparisons"] if c["against"] == "dagger-oracle")
    assert oracle["difference"] < 0 and oracle["ci_high"] < 0


@pytest.mark.parametrize("drop", ["dagger", "bc"])
def test_no_budget_reading_without_dagger_or_bc(drop):
    assert budget_reading([r for r in _rows() if r["method"] != drop]) is None


def test_each_metal_method_is_read_against_its_constant_twins_bc_refitted_and_the_best_gate():
    """``prior-ridge`` (a learned kind's prior) against ``prior-mean-da`` and ``prior-zero`` (its
    twins that ran), ``bc-refit`` and the best gate, at every budget and by the area; a twin itself
    is compared with nothing."""
    rows = _rows()
    for seed in range(6):
        rows += [
            _row("bc-refit", "2", seed, False, 100),
            _row("prior-ridge", "", seed, seed < 4, 100),
            _row("prior-mean-da", "", seed, seed < 1, 100),
            _row("prior-zero", "", seed, False, 100),
        ]
    reading = budget_reading(rows)
    for budget in reading["budgets"]:
        pairs = {(c["method"], c["against"]): c for c in budget["metal"]}
        assert set(pairs) == {
            ("prior-ridge", "prior-mean-da"),
            ("prior-ridge", "prior-zero"),
            ("prior-ridge", "bc-refit"),
            ("prior-ridge", "dagger-safe"),
        }
        assert pairs["prior-ridge", "prior-zero"]["only_a"] == 4 and pairs["prior-ridge", "prior-zero"]["only_b"] == 0
    auc = {(c["method"], c["against"]): c for c in reading["auc_metal"]}
    assert auc["prior-ridge", "prior-zero"]["difference"] == pytest.approx(4 / 6)


def test_the_refit_check_reads_each_refits_last_round_against_bc_on_the_whole_demonstration():
    def rows(method, setting, successes, fraction=1.0):
        return [
            {"method": method, "setting": setting, "demo_fraction": fraction, "seed": s, "success": ok, "reward": 1.0}
            for s, ok in enumerate(successes)
        ]

    bc = [True] * 8 + [False] * 2
    table = (
        rows("bc", "", bc)
        + rows("bc", "", [False] * 10, fraction=0.5)
        + rows("bc-refit", "3", [True] * 2 + [False] * 8)  # loses six of BC's seeds
        + rows("dagger", "1", [False] * 10)
        + rows("dagger", "3", [True] * 10)
    )
    checks = {c["method"]: c for c in refit_check(table)}
    assert set(checks) == {"bc-refit", "dagger"}
    assert checks["bc-refit"]["setting"] == "3" and checks["bc-refit"]["against"] == "bc"
    assert (checks["bc-refit"]["only_a"], checks["bc-refit"]["only_b"]) == (0, 6)
    assert checks["bc-refit"]["ci_high"] < 0
    assert checks["dagger"]["setting"] == "3" and (checks["dagger"]["only_a"], checks["dagger"]["only_b"]) == (2, 0)
    assert refit_check(rows("dagger", "3", [True] * 10)) == []


def test_the_reports_twin_table_puts_each_best_gate_under_the_budgets_where_it_is_best(tmp_path):
    """The safe gate is the best at the two smaller budgets, the random gate at the largest and by
    area: each comparison sits in its own budget's column, a dash in the others."""
    from metadagger.evaluation.benchmark.summary import summarize_benchmark
    from metadagger.evaluation.report.benchmark import benchmark_section
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.io import write_json

    rows = [r for r in _rows() if r["method"] not in ("dagger-safe", "dagger-oracle")]
    for seed in range(6):
        rows += [
            _row("dagger-safe", "0.8", seed, seed < 3, 120),
            _row("dagger-random", "0.5", seed, True, 190),
            _row("mdm-ridge", "", seed, seed < 4, 100),
        ]
    layout = RunLayout(tmp_path)
    rows = [{**r, "steps": 50} for r in rows]
    write_json(layout.benchmark_summary, summarize_benchmark(rows, {"pistar": 0, "pairs": 0}))
    lines = benchmark_section(layout)
    table = lines[lines.index("### MetaL DAgger against its constant twins") + 4 :]
    table = table[: table.index("")]
    split = [row.strip("| ").split(" | ") for row in table[2:]]
    cells = {tuple(row[:2]): row[2:] for row in split}
    assert all(len(row) == 4 for row in cells.values())  # three budgets and the area, on every row
    safe, random = cells["MDM Ridge", "DAgger, SafeDAgger gate"], cells["MDM Ridge", "DAgger, random gate"]
    assert [cell == "-" for cell in safe] == [False, False, True, True]
    assert [cell == "-" for cell in random] == [True, True, False, False]
    assert all(cell != "-" for cell in cells["MDM Ridge", "MDM mean-DA (control)"])
