"""The verdict block: a MetaL DAgger method beats its references only where every paired interval is above 0."""

from __future__ import annotations

from rows_kit import registry_context, rows

from metadagger.results.tables import BlockContext
from metadagger.results.verdict import verdict

NAME = "carracing-family-paper"
SHOWS = "(a difference shows from 20 points)"  # 4 of 20 seeds one way: smallest_shown_difference(20)


def _benchmark(ridge: int, mean_da: int) -> list[dict]:
    """BC, plain DAgger, BC refitted, a gate and MDM with Ridge and its twins; the demonstration is 500 queries."""
    return [
        *rows("bc", "", 0, 500),
        *rows("dagger", "3", 20, 3000),
        *rows("bc-refit", "3", 0, 500),
        *rows("dagger-safe", "0.5", 0, 1000),
        *rows("mdm-ridge", "", ridge, 500),
        *rows("mdm-mean-da", "", mean_da, 500),
        *rows("mdm-pistar-head", "", 0, 500),
    ]


def test_a_method_above_every_reference_is_named_with_its_intervals(tmp_path):
    context = registry_context(tmp_path, NAME, _benchmark(20, 0), confirm=_benchmark(10, 10))
    unseen, confirmation, both = verdict(context, NAME).splitlines()
    link = f"- [`{NAME}`](../results/{NAME}/report/report.md)"
    assert unseen.startswith(
        f"{link}, 20 unseen seeds {SHOWS}: above every one of its references: MDM Ridge at demonstration +5%"
    )
    # references with the same interval share it
    assert "against mean-DA, pi*'s head, BC refitted and DAgger, SafeDAgger gate, each +100 (+100 to +100)" in unseen
    # the confirmation seeds' reading, and the one on both sets, are items nested under the run's
    assert confirmation.startswith(f"  - 20 confirmation seeds {SHOWS}: none above all its references")
    assert "closest: MDM Ridge" in confirmation and "against mean-DA +0 (+0 to +0)" in confirmation
    # above on the unseen seeds alone: nothing is claimed
    assert both == (
        "  - both seed sets: no method is above all its references at the same reading on both, so none is claimed."
    )


def test_a_method_above_every_reference_on_both_seed_sets_is_named_once_more(tmp_path):
    context = registry_context(tmp_path, NAME, _benchmark(20, 0), confirm=_benchmark(20, 0))
    *_, both = verdict(context, NAME).splitlines()
    assert both.startswith(
        "  - both seed sets: above every one of its references on "
        "both: MDM Ridge at demonstration +5%; MDM Ridge at demonstration +10%"
    )
    assert "MDM Ridge by area." in both


def test_a_run_with_one_seed_set_or_nothing_above_on_either_gets_no_line_for_both(tmp_path):
    assert len(verdict(registry_context(tmp_path, NAME, _benchmark(20, 0)), NAME).splitlines()) == 1
    none = registry_context(tmp_path / "none", NAME, _benchmark(10, 10), confirm=_benchmark(10, 10))
    assert len(verdict(none, NAME).splitlines()) == 2


def test_a_stale_run_is_judged_from_its_rows_and_marked(tmp_path):
    line = verdict(registry_context(tmp_path, NAME, _benchmark(10, 10), stale=True), NAME)
    assert line.startswith(f"- [`{NAME}`](../results/{NAME}/report/report.md) (stale), 20 unseen seeds {SHOWS}: none")


def test_a_run_not_in_the_registry_says_how_to_add_it(tmp_path):
    line = verdict(BlockContext({}, tmp_path), "fetch-paper")
    assert line.startswith("- `fetch-paper`: *Not in the registry yet: `metadagger reproduce --task fetch")


def test_a_constant_twin_is_named_as_the_twin_and_other_intervals_stand_alone(tmp_path):
    made = [
        *rows("bc", "", 0, 500),
        *rows("dagger", "3", 10, 3000),
        *rows("bc-refit", "3", 0, 500),
        *rows("disagree-ridge", "0.8", 20, 1000),
        *rows("disagree-mean-da", "0.8", 10, 1000),
        *rows("disagree-pistar-head", "0.8", 0, 1000),
    ]
    line = verdict(registry_context(tmp_path, NAME, made), NAME)
    assert "against its mean-DA twin +" in line and "against its pi*-head twin and BC refitted, each +" in line
    assert "DAgger, gate: disagreement with mean-DA (control)" not in line
