"""A labelling session without a page: how a task is labelled, the scripted expert's session against the
benchmark's row, what a session writes, and how it resumes."""

from __future__ import annotations

import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest
from corridor_session import GATE, SEED, SETTING
from toy_task import CorridorTask

from metadagger.errors import CheckpointError, UserError
from metadagger.evaluation.benchmark.ledger import LABEL_FIELDS, SCRIPTED, effort, label_record
from metadagger.evaluation.rows import read_csv
from metadagger.label import session as session_module
from metadagger.label.forms import (
    DISPLACEMENT,
    STEERING,
    LabelForm,
    Refused,
    Slider,
    default_form,
    label_form,
    shown,
)
from metadagger.label.session import benchmark_gap, finished_rows, plan_of_run, run_label
from metadagger.label.store import LabelStore
from metadagger.pipeline.run_config import load_run
from metadagger.tasks.carracing.task import STEERING_VALUES, CarRacingTask
from metadagger.utils.jsonl import read_lines

# --- how a person labels a task ------------------------------------------------------------------


def test_carracing_is_labelled_by_its_20_steering_classes_left_to_right():
    form = label_form(CarRacingTask())
    assert form is STEERING and len(form.classes) == 20
    assert form.classes[0] == "left 0.40" and form.classes[9] == "left 0.02"
    assert form.classes[10] == "right 0.02" and form.classes[-1] == "right 0.40"
    assert [name.startswith("left") for name in form.classes] == list(STEERING_VALUES < 0)
    assert form.check(0) == 0 and form.check(19) == 19


def test_the_carracing_page_says_what_is_asked_and_names_straight():
    page = STEERING.as_json()
    assert page["marks"] == {"9": "straight", "10": "straight"}  # the two classes nearest zero, +-0.021
    assert abs(STEERING_VALUES[[9, 10]]).max() < 0.022
    asks = page["asks"]
    assert asks.startswith("Steering only (the scripted expert drives gas and brake)")
    assert "radians, from left 0.40 (full left) to right 0.40 (full right), 0.042 apart" in asks
    assert "the two marked straight (±0.021) are the nearest" in asks
    assert label_form(CorridorTask()).as_json()["asks"].startswith("Choose the class the expert would choose")
    with pytest.raises(UserError, match=r"label form marks \[3\] name no class"):
        LabelForm(classes=("a", "b", "c"), marks=((3, "straight"),))


def test_a_vector_task_gets_a_slider_per_dimension():
    assert [(s.name, s.low, s.high) for s in DISPLACEMENT.sliders] == [("x", -1, 1), ("y", -1, 1), ("z", -1, 1)]
    form = label_form(CorridorTask(discrete=False))  # declares nothing: its action space's default
    assert form == LabelForm(sliders=(Slider("dimension 0", -1.0, 1.0),))
    third = float(np.float32(1 / 3))
    assert form.check([1 / 3]) == [third]  # kept as the float32 the learner trains on
    assert label_form(CorridorTask()).classes == ("0", "1", "2")


@pytest.mark.parametrize(
    "form, value, says",
    [
        (STEERING, 20, "label 20 refused: expected a class index in [0, 19]"),
        (STEERING, -1, "label -1 refused: expected a class index in [0, 19]"),
        (STEERING, 3.0, "label 3.0 refused: expected a class index in [0, 19]"),
        (STEERING, True, "label True refused: expected a class index in [0, 19]"),
        (DISPLACEMENT, [0, 0], "label [0, 0] refused: expected a list of 3 numbers"),
        (DISPLACEMENT, [0, 1.5, 0], "label [0, 1.5, 0] refused: y must be a number in [-1, 1]"),
        (DISPLACEMENT, [0, "1", 0], "label [0, '1', 0] refused: y must be a number in [-1, 1]"),
        (DISPLACEMENT, [0, 10**400, 0], f"label {shown([0, 10**400, 0])} refused: y must be a number in [-1, 1]"),
        (STEERING, [7] * 1000, "label [7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7,"),
    ],
)
def test_a_label_out_of_range_is_refused_in_one_line(form, value, says):
    with pytest.raises(Refused) as refused:
        form.check(value)
    assert str(refused.value).startswith(says) and refused.value.status == 400
    assert len(str(refused.value)) < 200  # the value shown cut short, whatever its length


def test_a_task_declares_its_own_form_and_a_form_that_does_not_fit_is_named():
    class Named(CorridorTask):
        def person_labels(self) -> LabelForm:
            return LabelForm(classes=("left", "straight", "right"))

    class Wrong(CorridorTask):
        def person_labels(self) -> LabelForm:
            return LabelForm(classes=("left", "right"))

    assert label_form(Named()).classes == ("left", "straight", "right")
    with pytest.raises(UserError, match=r"person_labels\(\) must return a LabelForm with 3 classes, got LabelForm"):
        label_form(Wrong())
    with pytest.raises(UserError, match="no label form for action space Box"):
        default_form(gym.spaces.Box(-np.inf, np.inf, (2,)))


# --- the scripted expert's session ---------------------------------------------------------------


def _plan(run, seed: int = SEED, gate: str = GATE, setting: float = SETTING):
    return plan_of_run(run, load_run(run.root), seed=seed, gate=gate, setting=setting)


def test_the_scripted_session_makes_the_benchmarks_row_and_writes_every_round(run):
    rows = run_label(run, _plan(run), expert=SCRIPTED)
    session = run.label_session(SCRIPTED, "dagger-safe", "0.5", SEED)
    assert [r["round"] for r in rows] == [1, 2, 3]
    assert read_lines(session.rows, called="row") == rows
    assert sorted(p.name for p in (session.root / "heads").iterdir()) == [
        "1.safetensors",
        "2.safetensors",
        "3.safetensors",
    ]

    [logged] = read_lines(run.benchmark_log, called="row")  # the benchmark's log line of seed 300
    [benchmark] = logged["entries"]["dagger-safe@0.5"]["rows"]
    last = dict(rows[-1])
    assert last.pop("round") == 3
    assert json.dumps(last, sort_keys=True) == json.dumps(benchmark, sort_keys=True)  # the benchmark's own row
    [csv_row] = [r for r in read_csv(run.benchmark_table) if r["method"] == "dagger-safe"]
    assert int(csv_row["expert_queries"]) == last["expert_queries"] and int(csv_row["takeovers"]) == last["takeovers"]

    labels = read_lines(session.labels, called="label")
    asked = [(r["round"], s) for r in last["labels"][1:] for a, b in r["runs"] for s in range(a, b)]
    assert [(r["round"], r["step"]) for r in labels] == asked  # every asked state, in round and step order
    assert all(list(r) == sorted(LABEL_FIELDS) and r["who"] == SCRIPTED and r["seconds"] == 0.0 for r in labels)
    runs = sum(len(r["runs"]) for r in last["labels"][1:])
    assert effort(labels, 3) == {"labels": len(asked), "seconds": 0.0, "switches": runs, "labelled_by": SCRIPTED}
    assert len(asked) == last["expert_queries"] - 30  # the demonstration's 30 steps are round 0


def test_a_session_resumes_from_its_labels_and_asks_only_for_the_missing_ones(run):
    first = run_label(run, _plan(run), expert=SCRIPTED)
    session = run.label_session(SCRIPTED, "dagger-safe", "0.5", SEED)
    heads = {p.name: p.read_bytes() for p in (session.root / "heads").iterdir()}
    lines = session.labels.read_bytes().splitlines(keepends=True)
    session.labels.write_bytes(b"".join(lines[:5]) + lines[5][:17])  # killed while appending the sixth label
    killed_in = json.loads(lines[5])["round"]  # the rows of the rounds before it were written
    rows = session.rows.read_bytes().splitlines(keepends=True)
    session.rows.write_bytes(b"".join(rows[: killed_in - 1]))
    assert finished_rows(run, _plan(run), SCRIPTED) is None
    assert run_label(run, _plan(run), expert=SCRIPTED) == first
    assert session.labels.read_bytes().splitlines(keepends=True) == lines  # the torn line is given again, once
    assert {p.name: p.read_bytes() for p in (session.root / "heads").iterdir()} == heads


def test_a_finished_session_run_again_is_not_replayed(run, monkeypatch):
    first = run_label(run, _plan(run), expert=SCRIPTED)
    assert finished_rows(run, _plan(run), SCRIPTED) == first
    assert finished_rows(run, _plan(run)) is None  # a person's session of it is not begun

    def replayed(*args, **kwargs):
        raise AssertionError("a finished session was replayed")

    monkeypatch.setattr(session_module, "label_seed", replayed)
    assert run_label(run, _plan(run), expert=SCRIPTED) == first


def test_a_session_begun_from_other_inputs_is_refused(run):
    run_label(run, _plan(run), expert=SCRIPTED)
    changed = dataclasses.replace(_plan(run), rounds=2)
    with pytest.raises(UserError, match=r"was begun from other inputs \(rounds: 3 -> 2\); move that folder away"):
        run_label(run, changed, expert=SCRIPTED)


@pytest.mark.parametrize(
    "seed, gate, setting, says",
    [
        (200, GATE, SETTING, "--seed 200 was used for pi* or the pairs; label an unseen seed"),
        (SEED, "oracle", 0.5, "gate 'oracle' is a reference that reads the scripted expert's labels"),
        (SEED, "lazy", 0.5, "unknown gate 'lazy': expected one of random, ensemble, safe, novelty, least-confidence"),
        (SEED, "safe", 1.5, "SafeGate"),
    ],
)
def test_a_session_that_cannot_run_is_one_line_before_any_work(run, seed, gate, setting, says):
    with pytest.raises(UserError) as error:
        _plan(run, seed, gate, setting)
    assert says in str(error.value) and "\n" not in str(error.value) and "oracle, " not in str(error.value)
    assert not run.label_dir.exists()


@pytest.mark.parametrize(
    "seed, gate, setting, says",
    [
        (SEED, GATE, SETTING, None),
        (SEED, GATE, 0.8, "--setting 0.8 is not in the run's grid of dagger-safe (0.5), so the benchmark has no row"),
        (SEED, "random", 0.5, "the run's benchmark does not run dagger-random (benchmark.methods)"),
        (301, GATE, SETTING, "--seed 301 is not one of the run's benchmark.seeds (or confirm_seeds), so the benchmark"),
    ],
)
def test_a_session_the_benchmark_has_no_row_of_is_named(run, seed, gate, setting, says):
    gap = benchmark_gap(load_run(run.root), _plan(run, seed, gate, setting))
    assert gap == says if says is None else gap.startswith(says)


def test_the_store_refuses_a_second_label_and_a_foreign_line(tmp_path):
    store = LabelStore(tmp_path / "labels.jsonl", seed=7)
    record = label_record(7, 1, 4, 2, 1.2345, "person", True)
    assert record == {"seed": 7, "round": 1, "step": 4, "label": 2, "seconds": 1.234, "who": "person", "switch": True}
    store.add(record)
    with pytest.raises(Refused, match="round 1 step 4 is labelled already: a label is given once"):
        store.add(label_record(7, 1, 4, 1, 3.0, "person", True))
    assert len(store.path.read_text().splitlines()) == 1
    assert LabelStore(store.path, seed=7).given(1) == {4: record}
    with pytest.raises(CheckpointError, match="is not a label of seed 8"):
        LabelStore(store.path, seed=8)
