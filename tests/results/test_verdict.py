"""The verdict block: a MetaL DAgger method beats its references only where every paired interval is above 0."""

from __future__ import annotations

import json
from pathlib import Path

from metadagger.results.registry import RegistryRun
from metadagger.results.tables import BlockContext
from metadagger.results.verdict import verdict
from metadagger.utils.kernels import NUMERICS

CURRENT = {"machine": {"cpu": "CPU", "numerics": NUMERICS}}


def _comparison(method: str, against: str, low: float, high: float) -> dict:
    return {
        "method": method,
        "demo_fraction": 1.0,
        "against": against,
        "against_demo_fraction": 1.0,
        "difference": (low + high) / 2,
        "ci_low": low,
        "ci_high": high,
    }


def _summary(metal: list[dict], auc_metal: list[dict]) -> dict:
    return {"budgets": {"seeds": list(range(20)), "budgets": [{"share": 0.1, "metal": metal}], "auc_metal": auc_metal}}


def _run(tmp_path: Path, summary: dict, confirm: dict | None = None) -> BlockContext:
    run = tmp_path / "carracing-family-paper"
    (run / "benchmark" / "confirm").mkdir(parents=True)
    (run / "benchmark" / "summary.json").write_text(json.dumps(summary))
    if confirm is not None:
        (run / "benchmark" / "confirm" / "summary.json").write_text(json.dumps(confirm))
    return BlockContext({"carracing-family-paper": RegistryRun(run, CURRENT)}, tmp_path)


def test_a_method_above_every_reference_is_named_with_its_intervals(tmp_path):
    above = [
        _comparison("prior-ridge", "prior-mean-da", 0.05, 0.35),
        _comparison("prior-ridge", "bc-refit", 0.10, 0.40),
        _comparison("prior-ridge", "dagger-thrifty", 0.02, 0.20),
    ]
    one_below = [_comparison("mdm-ridge", "mdm-mean-da", 0.1, 0.3), _comparison("mdm-ridge", "bc-refit", -0.1, 0.2)]
    context = _run(tmp_path, _summary(above + one_below, one_below), confirm=_summary(one_below, one_below))
    unseen, confirmation = verdict(context, "carracing-family-paper").splitlines()
    assert unseen.startswith("- `carracing-family-paper`, 20 unseen seeds: above every one of its references: ")
    twin = "against BC, prior toward mean-DA (control) +20 points (+5 to +35)"
    assert f"BC, prior toward Ridge at demonstration +10%, {twin}" in unseen
    assert "MDM Ridge" not in unseen  # one interval holds 0
    assert confirmation.startswith("- `carracing-family-paper`, 20 confirmation seeds: no MetaL DAgger method is above")


def test_with_none_above_the_closest_is_the_highest_lowest_bound(tmp_path):
    metal = [
        _comparison("mdm-ridge", "mdm-mean-da", -0.30, 0.10),
        _comparison("mdm-ridge", "bc-refit", 0.05, 0.30),
        _comparison("disagree-ridge", "disagree-mean-da", -0.05, 0.20),
        _comparison("disagree-ridge", "bc-refit", 0.00, 0.25),
    ]
    line = verdict(_run(tmp_path, _summary(metal, [])), "carracing-family-paper")
    assert "no MetaL DAgger method is above all of its references" in line
    assert "Closest: DAgger, gate: disagreement with Ridge at demonstration +10%" in line


def test_a_run_not_in_the_registry_says_how_to_add_it(tmp_path):
    line = verdict(BlockContext({}, tmp_path), "fetch-paper")
    assert line.startswith("- `fetch-paper`: *Not in the registry yet: `metadagger reproduce --task fetch")
