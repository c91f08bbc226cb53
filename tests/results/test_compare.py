"""Old against new: a run's success rates beside another's 95% intervals."""

from __future__ import annotations

import pytest

from metadagger.errors import UserError
from metadagger.evaluation.rows import write_csv
from metadagger.results.compare import compare_runs, comparison_lines


def _table(folder, name, successes, n=10):
    (folder / "eval").mkdir(parents=True, exist_ok=True)
    return [{"method": name, "seed": 5000 + i, "success": i < successes} for i in range(n)]


def test_a_rate_outside_the_old_interval_is_named_and_renamed_methods_are_matched(tmp_path):
    old, new = tmp_path / "old", tmp_path / "new"
    # mdm.csv: bc 0/10 -> 0/10 (inside), dm 2/10 -> 9/10 (outside: Wilson 5.7%-51.0%)
    for folder, dm in ((old, 2), (new, 9)):
        rows = _table(folder, "bc", 0) + _table(folder, "dm", dm)
        write_csv(folder / "eval" / "mdm.csv", rows, fields=("method", "seed", "success"))
    # mdi.csv: the old name "dagger-bc" is today's "dagger-bc-init"
    for folder, name in ((old, "dagger-bc"), (new, "dagger-bc-init")):
        rows = [{"method": name, "seed": s, "one_shot_success": s % 2 == 0, "two_shot_success": True} for s in range(4)]
        write_csv(folder / "eval" / "mdi.csv", rows, fields=("method", "seed", "one_shot_success", "two_shot_success"))
    comparison = compare_runs(old, new)
    found = {(r["table"], r["column"], r["method"]): r for r in comparison["rows"]}
    assert found["eval/mdm.csv", "success", "bc"]["inside"]
    dm = found["eval/mdm.csv", "success", "dm"]
    assert dm["old"] == [2, 10] and dm["new"] == [9, 10] and not dm["inside"]
    assert dm["old_interval"][0] == pytest.approx(0.0567, abs=1e-3) and dm["old_interval"][1] == pytest.approx(
        0.5098, abs=1e-3
    )
    assert found["eval/mdi.csv", "one_shot_success", "dagger-bc-init"]["inside"]
    assert comparison["outside"] == [dm] and comparison["only_old"] == comparison["only_new"] == []
    assert comparison_lines(comparison)[-1] == "1 of 4 rates outside the old run's 95% interval."


def test_runs_that_share_no_table_or_do_not_exist_are_one_line(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with pytest.raises(UserError, match="share none of the tables"):
        compare_runs(tmp_path / "a", tmp_path / "b")
    with pytest.raises(UserError, match="no run folder at"):
        compare_runs(tmp_path / "a", tmp_path / "missing")
