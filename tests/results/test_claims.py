"""The findings' claim blocks: each line's numbers come from the run's rows, and its words from their intervals."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from rows_kit import registry_context, rows

from metadagger.evaluation.benchmark.coverage import rank_interval
from metadagger.results.blocks import wrap_prose
from metadagger.results.claims import claim
from metadagger.results.tables import BlockContext

REPOSITORY = Path(__file__).resolve().parents[2]
NAME = "carracing-paper"


@pytest.fixture
def run_rows() -> list[dict]:
    return [
        *rows("bc", "", 10, 500),
        *rows("bc-refit", "3", 10, 500),
        *rows("dagger", "3", 20, 3000),
        *rows("mdm-ridge", "", 18, 500),
        *rows("mdm-mean-da", "", 17, 500),
        *rows("mdm-pistar-head", "", 2, 500),
        *rows("dagger-safe", "0.5", 14, 1200),
        *rows("dagger-oracle", "0.5", 4, 2000),
    ]


def _line(context: BlockContext, kind: str) -> str:
    lines = claim(context, kind, "carracing-paper").splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_the_mapper_line_names_its_paired_intervals_and_what_they_show(tmp_path, run_rows):
    line = _line(registry_context(tmp_path, NAME, run_rows, stale=True), "mappers")
    assert line.startswith("- [`carracing-paper`](../results/carracing-paper/report/report.md) (stale): ")
    assert "best mapper MDM Ridge 18/20" in line
    assert "against pi*'s head +80 (+" in line  # 18 against 2 of 20
    assert "against mean-DA +5 (" in line and "against BC refitted +40 (+" in line
    assert line.endswith(": better than pi*'s head, BC refitted; not shown better than mean-DA.")


def test_a_mapper_below_a_reference_is_said_to_be_below_it(tmp_path, run_rows):
    made = [r for r in run_rows if not r["method"].startswith("mdm-")]
    made += [*rows("mdm-ridge", "", 0, 500), *rows("mdm-mean-da", "", 0, 500), *rows("mdm-pistar-head", "", 0, 500)]
    line = _line(registry_context(tmp_path, NAME, made), "mappers")
    assert line.endswith(": not shown better than pi*'s head, mean-DA; below BC refitted.")


def test_refits_and_labels_read_against_bc_and_bc_refitted(tmp_path, run_rows):
    context = registry_context(tmp_path, NAME, run_rows)
    refits = _line(context, "refits")
    assert "BC refitted after 3 rounds +0 (+0 to +0) against BC, not shown below BC" in refits
    assert "DAgger after 3 rounds +50 (+" in refits and refits.endswith("above BC.")
    labels = _line(context, "labels")
    assert "DAgger after 3 rounds 20/20 at 3,000 queries, BC refitted 10/20 at 500 queries: +50 (" in labels
    assert labels.endswith("the labels add to the training.")


def test_the_labels_claim_reads_dagger_against_dart_at_its_labels_where_the_run_has_dart(tmp_path, run_rows):
    made = [*run_rows, *rows("dart", "3", 8, 3000)]
    labels = _line(registry_context(tmp_path, NAME, made), "labels")
    assert "the labels add to the training; DART at DAgger's labels 8/20: +60 (+" in labels
    assert labels.endswith("the learner's states above more demonstrations.")
    same = _line(registry_context(tmp_path / "tie", NAME, [*run_rows, *rows("dart", "3", 20, 3000)]), "labels")
    assert same.endswith("DART at DAgger's labels 20/20: +0 (+0 to +0), not shown above more demonstrations.")


def test_the_gates_claim_reads_the_cheapest_gate_at_daggers_success_against_random_spending_no_fewer(
    tmp_path, run_rows
):
    random = [*rows("dagger-random", "0.05", 4, 1100), *rows("dagger-random", "0.2", 6, 1300)]
    made = [*run_rows, *rows("dagger-ensemble", "0.5", 20, 1250), *rows("dagger-ensemble", "0.8", 19, 900), *random]
    line = _line(registry_context(tmp_path, NAME, made), "gates")
    assert "DAgger, ensemble gate 0.5 reaches DAgger's 20/20 with the fewest labels, 20/20 at 1,250 queries" in line
    # the random setting at 1,100 spends fewer labels than the gate: the one at 1,300 is its match
    assert "against the random gate spending no fewer (0.2: 6/20 at 1,300 queries) +70 (+" in line
    assert line.endswith("above random.")
    none_reach = _line(registry_context(tmp_path / "short", NAME, [*run_rows, *random]), "gates")
    assert "no gate reaches DAgger's 20/20; the closest, DAgger, SafeDAgger gate 0.5, has 14/20" in none_reach
    assert none_reach.endswith("(0.2: 6/20 at 1,300 queries) +40 (+20 to +60), above random.")
    cheapest = _line(
        registry_context(tmp_path / "cheap", NAME, [*run_rows, *rows("dagger-random", "0.05", 20, 900)]), "gates"
    )
    assert cheapest.endswith(", the random gate itself.")
    no_random = _line(registry_context(tmp_path / "alone", NAME, run_rows), "gates")
    assert no_random.endswith("no setting of the random gate spends as many labels.")


def test_a_refit_that_loses_what_bc_had_is_said_so(tmp_path, run_rows):
    made = [r for r in run_rows if r["method"] != "dagger"] + rows("dagger", "3", 0, 3000)
    line = _line(registry_context(tmp_path, NAME, made), "refits")
    assert "; DAgger after 3 rounds -50 (-" in line and line.endswith(") against BC, loses what BC had.")


def test_the_oracle_is_read_against_the_best_gate(tmp_path, run_rows):
    line = _line(registry_context(tmp_path, NAME, run_rows), "oracle")
    assert "the rule at 0.5 4/20 at 2,000 queries, the best gate (DAgger, SafeDAgger gate 0.5) 14/20 at 1,200" in line
    assert line.endswith("the best gate above the rule.")


def test_runs_without_the_rows_a_claim_reads_are_named_in_one_line(tmp_path, run_rows):
    made = [r for r in run_rows if r["method"] not in ("bc-refit", "dagger-oracle")]
    context = registry_context(tmp_path, NAME, made)
    for kind in ("labels", "oracle"):
        assert claim(context, kind, "carracing-paper") == "\n*Without the rows this claim reads: `carracing-paper`.*"
    text = claim(context, "refits", "carracing-paper,fetch-paper")
    assert text.endswith("*Without the rows this claim reads: `fetch-paper` (not in the registry yet).*")
    with pytest.raises(ValueError, match="claim 'ceiling' is not one of mappers, refits"):
        claim(context, "ceiling", "carracing-paper")


def test_the_rank_correlation_interval_holds_rho_and_narrows_with_seeds():
    low, high = rank_interval(0.5, 20)
    assert -1 < low < 0.5 < high < 1
    wide, narrow = rank_interval(0.5, 10), rank_interval(0.5, 100)
    assert wide[0] < low < narrow[0] and narrow[1] < high < wide[1]
    assert rank_interval(-0.3, 20) == pytest.approx(tuple(-x for x in reversed(rank_interval(0.3, 20))))
    assert rank_interval(None, 20) is None and rank_interval(0.9, 3) is None
    # Fisher's z with Bonett and Wright's variance, by hand
    half = 1.959963984540054 * math.sqrt((1 + 0.5**2 / 2) / 17)
    assert low == pytest.approx(math.tanh(math.atanh(0.5) - half))


def test_a_list_item_whose_first_word_is_longer_than_the_line_keeps_it_beside_its_marker():
    link = "[`carracing-family-paper-per-seed-init`](../results/carracing-family-paper-per-seed-init/report.md)"
    wrapped = wrap_prose(f"- {link} (stale): one two three four five six seven eight nine ten eleven twelve.")
    first, *rest = wrapped.splitlines()
    assert first == f"- {link}" and all(line.startswith("  ") for line in rest)


def test_the_findings_page_and_the_readme_stay_short():
    findings = (REPOSITORY / "docs" / "findings.md").read_text().splitlines()
    readme = (REPOSITORY / "README.md").read_text().splitlines()
    assert len(findings) <= 250 and len(readme) <= 180
    long = [
        (name, i + 1)
        for name, lines in (("findings", findings), ("README", readme))
        for i, line in enumerate(lines)
        if len(line) > 200
    ]
    assert not long, long


def _gap_rows(*, gain_with_gap: bool = True) -> list[dict]:
    """Plain DAgger with a gap growing over the seeds; MDM Ridge solving the seeds with the larger
    gaps only (or the smaller ones); its twins failing every seed; the same three from half the
    demonstration failing every seed (no rank)."""
    dagger = rows("dagger", "3", 20, 3000)
    for i, row in enumerate(dagger):
        row["coverage_gap"] = i / 20  # the later seeds, the larger gaps
    ridge = rows("mdm-ridge", "", 20, 500)
    for i, row in enumerate(ridge):
        row["success"] = (i >= 10) == gain_with_gap
    half = [
        {**row, "demo_fraction": 0.5}
        for row in (
            *rows("mdm-ridge", "", 0, 250),
            *rows("mdm-mean-da", "", 0, 250),
            *rows("mdm-pistar-head", "", 0, 250),
        )
    ]
    return [
        *rows("bc", "", 0, 500),
        *dagger,
        *ridge,
        *rows("mdm-mean-da", "", 0, 500),
        *rows("mdm-pistar-head", "", 0, 500),
        *half,
    ]


def test_the_coverage_line_counts_the_rank_correlations_and_gives_the_highest_with_its_interval(tmp_path):
    line = _line(registry_context(tmp_path, NAME, _gap_rows()), "coverage")
    rho = "+0.87 (+0.64 to +0.95)"  # the gains are 0 on the first ten seeds, 1 on the last ten
    assert line == (
        f"- [`{NAME}`](../results/{NAME}/report/report.md): over 20 seeds, rho above 0 in 2 of 2 comparisons, "
        f"below in 0 (0.1 each way by chance; 2 more without a rank); highest {rho}, MDM Ridge against pi*'s head."
    )


def test_the_coverage_line_gives_the_lowest_rho_only_where_some_lie_below_0(tmp_path):
    line = _line(registry_context(tmp_path, NAME, _gap_rows(gain_with_gap=False)), "coverage")
    rho = "-0.87 (-0.95 to -0.64)"  # the gains are 1 on the first ten seeds, 0 on the last ten
    assert line.endswith(
        f"rho above 0 in 0 of 2 comparisons, below in 2 (0.1 each way by chance; 2 more without a rank); "
        f"highest {rho}, MDM Ridge against pi*'s head; lowest {rho}, MDM Ridge against mean-DA."
    )


def test_the_coverage_claim_names_the_comparisons_above_0_on_both_seed_sets(tmp_path):
    context = registry_context(tmp_path, NAME, _gap_rows(), confirm=_gap_rows())
    *_, both = claim(context, "coverage", NAME).splitlines()
    assert (
        both == "  - both seed sets: rho above 0 on both in 2 comparisons, each of MDM Ridge against a constant twin."
    )
    reversed_gain = registry_context(tmp_path / "other", NAME, _gap_rows(), confirm=_gap_rows(gain_with_gap=False))
    *_, confirmation, both = claim(reversed_gain, "coverage", NAME).splitlines()
    assert "rho above 0 in 0 of 2 comparisons, below in 2" in confirmation
    assert both == "  - both seed sets: rho above 0 on both in no comparison."


def test_a_coverage_comparison_from_part_of_the_demonstration_is_named_so(tmp_path):
    dagger = [{**row, "coverage_gap": i / 20} for i, row in enumerate(rows("dagger", "3", 20, 3000))]
    ridge = [
        {**row, "demo_fraction": 0.5, "success": i % 2 == 0} for i, row in enumerate(rows("mdm-ridge", "", 0, 250))
    ]
    twin = [{**row, "demo_fraction": 0.5} for row in rows("mdm-mean-da", "", 0, 250)]
    made = [*rows("bc", "", 0, 500), *dagger, *ridge, *twin]
    line = _line(registry_context(tmp_path, NAME, made), "coverage")
    assert "rho above 0 in 0 of 1 comparison, below in 0 (0.0 each way by chance); -0.09 (" in line
    assert "highest" not in line and line.endswith("), MDM Ridge (50% of the demonstration) against mean-DA.")


def test_a_run_with_confirmation_seeds_has_each_claim_read_again_on_them(tmp_path, run_rows):
    confirm = [r for r in run_rows if r["method"] != "mdm-ridge"] + rows("mdm-ridge", "", 2, 500)
    context = registry_context(tmp_path, NAME, run_rows, confirm=confirm)
    unseen, confirmation = claim(context, "mappers", NAME).splitlines()
    assert unseen.startswith(f"- [`{NAME}`](../results/{NAME}/report/report.md): best mapper MDM Ridge 18/20")
    assert confirmation.startswith("  - confirmation seeds: ")  # an item nested under the run's
    assert "best mapper MDM Ridge 2/20" in confirmation
    assert len(claim(context, "labels", NAME).splitlines()) == 2


def test_a_claim_read_on_the_confirmation_seeds_alone_names_them_in_the_runs_own_item(tmp_path, run_rows):
    unseen = [r for r in run_rows if r["method"] != "bc-refit"]  # no BC refitted: no labels claim there
    context = registry_context(tmp_path, NAME, unseen, confirm=run_rows)
    (line,) = claim(context, "labels", NAME).splitlines()
    assert line.startswith(
        f"- [`{NAME}`](../results/{NAME}/report/report.md), confirmation seeds: DAgger after 3 rounds"
    )
