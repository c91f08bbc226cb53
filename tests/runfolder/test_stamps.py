"""What a stale artifact's message says changed: each setting once, lists by what they gained and lost."""

from __future__ import annotations

from metadagger.runfolder.stamps import describe_changes


def test_a_changed_setting_is_named_with_its_old_and_new_value_nested_fields_joined_by_dots():
    old = {"pairs": {"dagger_rounds": 3, "bc": {"lr": 0.01}}, "pistar_fingerprint": "a", "kept": 1}
    new = {"pairs": {"dagger_rounds": 4, "bc": {"lr": 0.001}}, "pistar_fingerprint": "b", "kept": 1}
    assert describe_changes(old, new) == [
        "pairs.bc.lr: 0.01 -> 0.001",
        "pairs.dagger_rounds: 3 -> 4",
        "pistar: changed",
    ]
    assert describe_changes({}, {"lanes": 8}) == ["lanes: (default) -> 8"]


def test_a_list_of_names_says_what_it_gained_and_lost_not_two_cut_prefixes():
    old = {"methods": ["bc", "mdm", "dagger", "dagger-random"]}
    new = {"methods": ["bc", "mdm", "dagger", "bc-refit", "prior", "prior-dagger", "disagree", "dagger-safe"]}
    assert describe_changes(old, new) == [
        'methods: added "bc-refit", "prior", "prior-dagger", "disagree" and 1 more; removed "dagger-random"'
    ]
    assert describe_changes({"methods": ["a", "b"]}, {"methods": ["b", "a"]}) == ["methods: reordered"]


def test_a_seed_list_is_written_as_its_ranges():
    old = {"seeds": list(range(5000, 5020)), "confirm": []}
    new = {"seeds": [*range(5000, 5040), 7], "confirm": list(range(9000, 9040))}
    assert describe_changes(old, new) == ["confirm: [] -> 9000-9039", "seeds: 5000-5019 -> 5000-5039,7"]
