"""The budgets block: every run read at equal budgets and by area, on each seed set it has."""

from __future__ import annotations

from rows_kit import registry_context, rows

from metadagger.results.tables import budgets_table

NAME = "fetch-paper"


def _made(safe: int) -> list[dict]:
    return [
        *rows("bc", "", 0, 500),
        *rows("dagger", "3", 20, 3000),
        *rows("dagger-safe", "0.5", safe, 1000),
        *rows("mdm-ridge", "", 0, 500),
    ]


def test_each_seed_set_has_its_rows_and_the_best_at_each_budget(tmp_path):
    table = budgets_table(registry_context(tmp_path, NAME, _made(20), confirm=_made(0)), NAME).splitlines()
    unseen = [line for line in table if line.startswith(f"| `{NAME}` |")]
    confirmation = [line for line in table if line.startswith(f"| `{NAME}`, confirmation seeds |")]
    assert len(unseen) == len(confirmation) == 4  # three budgets, then the area
    assert unseen[2] == f"| `{NAME}` | +25% | DAgger, SafeDAgger gate | 100.0% | = | - |"
    # the gate solves nothing on the second set: plain DAgger is best there, read against the gate
    assert confirmation[2] == f"| `{NAME}`, confirmation seeds | +25% | DAgger | 0.0% | +0 (+0 to +0) | - |"
    assert confirmation[3] == f"| `{NAME}`, confirmation seeds | area | DAgger | 0.06 | +6 (+6 to +6) | - |"


def test_a_run_without_confirmation_seeds_has_rows_for_its_unseen_seeds_alone(tmp_path):
    table = budgets_table(registry_context(tmp_path, NAME, _made(20)), NAME)
    assert "confirmation seeds |" not in table and f"| `{NAME}` | area |" in table
