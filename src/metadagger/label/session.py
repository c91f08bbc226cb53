"""One seed of a run labelled by a person at a page (or by the scripted expert): a gate's DAgger rounds, resumable.

A session is the benchmark's chain for one gated method at one setting on one seed (its start:
the demonstration, w_BC and w_BC's rollout; then :func:`~metadagger.metal_dagger.method.dagger_rounds`)
with the rounds' labels answered by :class:`Answers`: the labels kept from an earlier call first,
then the scripted expert's, or a person's at the page (:class:`~metadagger.label.desk.Desk`). Every
rollout and refit is a function of the seed and the labels, so a resumed session replays the
rounds already labelled and asks only for what is missing. After each round it writes the head
(``heads/<round>.safetensors``) and the benchmark's row after that round (``rows.jsonl``); a
session whose last round's row is written is finished, and running it again changes nothing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.ledger import PERSON, SCRIPTED, demonstration_record, label_record, round_record
from metadagger.evaluation.benchmark.methods import GateKey
from metadagger.evaluation.benchmark.seed_chains import benchmark_row
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.gate_registry import (
    GATED_PREFIX,
    check_gates_serve,
    gate_declarations,
    gated_names,
    get_gate,
    make_gate,
)
from metadagger.imitation.rollouts import Trajectory, stack_labels
from metadagger.label.desk import Desk
from metadagger.label.forms import LabelForm, label_form
from metadagger.label.overview import OverviewRecorder, overview_of
from metadagger.label.server import PageServer
from metadagger.label.store import LabelStore
from metadagger.metal_dagger.method import Labeller, SeedLearner, bc_head, dagger_rounds, demonstration, seeded
from metadagger.pipeline.run_config import RunConfig
from metadagger.pipeline.stage_inputs import stage_inputs
from metadagger.runfolder.layout import LabelSessionLayout, RunLayout
from metadagger.runfolder.lock import run_lock
from metadagger.runfolder.stamps import describe_changes, file_fingerprint, stamp_of
from metadagger.tasks.base import Task
from metadagger.tasks.identity import task_stamp
from metadagger.utils.io import read_json, save_tensors, write_json
from metadagger.utils.jsonl import read_lines, write_lines
from metadagger.utils.kernels import kernel_stamp

#: Who may answer a session's queries.
EXPERTS = (PERSON, SCRIPTED)
#: Seconds the page is still served after the last round, so that it can say the session is done.
LINGER = 1.5


@dataclass(frozen=True)
class LabelPlan:
    """One gated method at one setting on one seed, with the run's fits: what a session runs."""

    task: Task
    pistar: Path
    """pi*'s file."""
    seed: int
    gate: str
    """A gate's name (:func:`~metadagger.imitation.gate_registry.gate_declarations`), not a reference."""
    setting: float
    """The value of the gate's ``setting`` field."""
    gate_options: dict[str, Any]
    """The gate's other fields (the run's ``benchmark`` options for ``dagger-<gate>``)."""
    rounds: int
    """R: the pairs' DAgger rounds."""
    bc: BCConfig
    dagger_bc: BCConfig
    early_stop: float | None

    def __post_init__(self) -> None:
        declaration = get_gate(self.gate)
        if declaration.reference:
            raise UserError(
                f"gate {self.gate!r} is a reference that reads the scripted expert's labels, which a person's session "
                f"never shows; choose a gate that is a method, e.g. random, safe or ensemble"
            )
        make_gate(self.gate, self.setting, **self.gate_options)  # its range checks, before any work

    @property
    def key(self) -> GateKey:
        """The benchmark's key of the method at this setting: the session's rows are its rows."""
        return GateKey(GATED_PREFIX + self.gate, f"{self.setting:g}", gate=self.gate, value=float(self.setting))

    def stamp(self, expert: str) -> dict[str, Any]:
        """What the session is made from; a resumed session must be made from the same."""
        return {
            "protocol": "label",
            **kernel_stamp(),
            **task_stamp(self.task),
            "pistar_fingerprint": file_fingerprint(self.pistar),
            "seed": self.seed,
            "method": self.key.method,
            "setting": self.key.setting,
            "gate": self.gate_options,
            "rounds": self.rounds,
            "bc": stamp_of(self.bc),
            "dagger_bc": stamp_of(self.dagger_bc),
            "early_stop": self.early_stop,
            "expert": expert,
        }

    def session(self, layout: RunLayout, expert: str) -> LabelSessionLayout:
        """The session's folder in run folder ``layout``."""
        return layout.label_session(expert, self.key.method, self.key.setting, self.seed)


class Answers:
    """Who labels a round's states (:data:`~metadagger.metal_dagger.method.Labeller`): the labels kept
    from an earlier call first; then the scripted expert's (``desk`` None) or a person's at the page.

    Args:
        store: the session's labels.
        form: how the task is labelled (the kind and size of a label).
        seed: the session's seed.
        desk: the page's desk, for a person; None for the scripted expert.
        recorder: the snapshots of the rolled-out episodes the page's overview is drawn from
            (:mod:`~metadagger.label.overview`); None: the page shows the frames alone.
    """

    def __init__(
        self,
        store: LabelStore,
        form: LabelForm,
        seed: int,
        desk: Desk | None = None,
        recorder: OverviewRecorder | None = None,
    ) -> None:
        self.store, self.form, self.seed, self.desk, self.recorder = store, form, seed, desk, recorder

    def __call__(self, index: int, rollout: Trajectory, asked: np.ndarray) -> np.ndarray:
        """The labels of ``asked`` steps of round ``index``'s ``rollout``, in the layout of its expert labels."""
        kept = self.store.given(index)
        strays = sorted(set(kept) - {int(s) for s in asked})
        if strays:
            raise UserError(
                f"{self.store.path} holds labels of round {index} steps {strays[:5]}, which this round did not ask: "
                "the session's states changed; move that folder away to start the session again"
            )
        waiting = [int(s) for s in asked if int(s) not in kept]
        if waiting and self.desk is None:
            asked_set = {int(s) for s in asked}
            for step in waiting:
                label = self.form.check(_plain(rollout.expert_labels[step]))
                self.store.add(label_record(self.seed, index, step, label, 0.0, SCRIPTED, step - 1 not in asked_set))
        elif waiting:
            overview = None if self.recorder is None else self.recorder.pictures(rollout)
            self.desk.ask(index, rollout, asked, waiting, overview)
        given = self.store.given(index)
        labels = stack_labels([given[int(s)]["label"] for s in asked], discrete=bool(self.form.classes))
        return labels.astype(rollout.expert_labels.dtype, copy=False)


def _plain(label: np.ndarray) -> int | list[float]:
    """An expert label as JSON holds it: a class index, or a list of floats."""
    value = np.asarray(label)
    return int(value) if value.ndim == 0 else [float(x) for x in value.reshape(-1)]


def label_seed(
    plan: LabelPlan, session: LabelSessionLayout, answers: Answers, desk: Desk | None = None
) -> list[dict[str, Any]]:
    """Run (or resume) ``plan``'s rounds with ``answers`` labelling them; the benchmark rows after each round.

    Writes, after each round, its head and every row so far into ``session``; ``desk`` (where a
    person answers) is told where the loop is, and ``answers``' recorder, where it has one, records
    the learner's episodes for the page's overview.
    """
    key, seed = plan.key, plan.seed
    tell = desk.working if desk is not None else (lambda message, **_: None)
    with SeedLearner(plan.task, str(plan.pistar), seed, head_init_seed=plan.bc.head_init_seed(seed)) as learner:
        if answers.recorder is not None:  # its episodes run one at a time in this env (no lane)
            learner.env = answers.recorder.wrap(learner.env)
        fresh = learner.head()
        demo = demonstration(learner)
        w_bc = bc_head(learner, demo.to_dataset(), seeded(plan.bc, seed))
        first = learner.roll(w_bc, early_stop=plan.early_stop)
        ledger, rows = [demonstration_record(len(demo.obs))], []
        tell("round 1: the gate chooses the states of w_BC's rollout", round=0, queries=len(demo.obs), rollout=first)
        rounds = dagger_rounds(
            learner,
            start=w_bc,
            first_rollout=first,
            demo=demo,
            rounds=plan.rounds,
            fit=seeded(plan.dagger_bc, seed),
            gate=make_gate(plan.gate, plan.setting, **plan.gate_options),
            early_stop=plan.early_stop,
            origin=fresh,
            labeller=_telling(answers, tell),
        )
        for r in rounds:
            ledger.append(round_record(r.index, r.asked, r.scores))
            rows.append({"round": r.index, **benchmark_row(key, seed, r.rollout, r.queries, list(ledger))})
            metadata = {"method": key.method, "setting": key.setting, "seed": str(seed), "round": str(r.index)}
            save_tensors(session.head(r.index), {"head": torch.from_numpy(r.head)}, metadata)
            write_lines(session.rows, rows)
            following = f"round {r.index + 1}: the gate chooses the states" if r.index < plan.rounds else "done"
            tell(
                f"round {r.index} refitted and rolled out; {following}",
                round=r.index,
                queries=r.queries,
                rollout=r.rollout,
            )
    return rows


def _telling(answers: Answers, tell: Callable[..., None]) -> Labeller:
    """``answers``, saying when a round's labels are in and its refit starts."""

    def labeller(index: int, rollout: Trajectory, asked: np.ndarray) -> np.ndarray:
        labels = answers(index, rollout, asked)
        tell(f"round {index}: every label is in; refitting the head and rolling it out")
        return labels

    return labeller


def plan_of_run(layout: RunLayout, config: RunConfig, *, seed: int, gate: str, setting: float) -> LabelPlan:
    """The session of ``gate`` at ``setting`` on ``seed`` of a run: its task, its current pi*, the
    pairs' rounds, fits and early stop, and the gate's options of its ``benchmark`` section.

    Raises:
        UserError: ``seed`` is one of pi*'s or the pairs' seeds, pi* is missing or made from
            another config, or the gate or its setting is not one a session takes (a gate of class
            distributions on a task with action vectors among them).
    """
    used = config.seen_seeds
    if seed in used:
        raise UserError(
            f"--seed {seed} was used for pi* or the pairs; label an unseen seed, e.g. one of benchmark.seeds"
        )
    if gate not in gate_declarations():  # the gates a session takes: the references are refused by LabelPlan
        raise UserError(f"unknown gate {gate!r}: expected one of {', '.join(gated_names())}")
    task = stage_inputs(layout, config).task
    check_gates_serve([GATED_PREFIX + gate], discrete=task.is_discrete, task=config.task)
    bench = config.benchmark if config.benchmark is not None else BenchmarkConfig()
    return LabelPlan(
        task=task,
        pistar=layout.pistar,
        seed=seed,
        gate=gate,
        setting=setting,
        gate_options=bench.options_of(GATED_PREFIX + gate),
        rounds=config.pairs.dagger_rounds,
        bc=config.pairs.bc,
        dagger_bc=config.pairs.dagger_bc,
        early_stop=config.pairs.early_stop,
    )


def benchmark_gap(config: RunConfig, plan: LabelPlan) -> str | None:
    """Why the run's benchmark has no row of ``plan``'s method, setting and seed to hold the session
    against (a gate, setting or seed it does not run); None where it has one."""
    bench = config.benchmark if config.benchmark is not None else BenchmarkConfig()
    method = plan.key.method
    if method not in bench.methods:
        return f"the run's benchmark does not run {method} (benchmark.methods), so it has no row to compare with"
    grid = [f"{value:g}" for value in bench.grid(method)]
    if plan.key.setting not in grid:
        return (
            f"--setting {plan.key.setting} is not in the run's grid of {method} ({', '.join(grid)}), so the benchmark "
            "has no row to compare with; choose one of those"
        )
    if plan.seed not in (*bench.seeds, *bench.confirm_seeds):
        return (
            f"--seed {plan.seed} is not one of the run's benchmark.seeds (or confirm_seeds), so the benchmark has no "
            "row to compare with; choose one of those"
        )
    return None


def finished_rows(layout: RunLayout, plan: LabelPlan, expert: str = PERSON) -> list[dict[str, Any]] | None:
    """The rows of ``plan``'s session where every round's is written (the session is finished), else None."""
    rows = plan.session(layout, expert).rows
    kept = read_lines(rows, called="row") if rows.is_file() else []
    return kept if [r["round"] for r in kept] == list(range(1, plan.rounds + 1)) else None


def run_label(
    layout: RunLayout,
    plan: LabelPlan,
    *,
    expert: str = PERSON,
    port: int = 0,
    announce: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """Run or resume ``plan``'s session in run folder ``layout``; the benchmark rows after each round.

    With ``expert`` ``person`` the page is served on the loopback address (``port``; 0: a free one)
    and ``announce`` is given its URL, token included, before the first round; with ``scripted``
    the task's scripted expert answers, with no page. A finished session (:func:`finished_rows`)
    is not run again: its rows are returned, and no page is served.

    Raises:
        UserError: another process holds the session, or its folder was begun from other inputs.
    """
    if expert not in EXPERTS:
        raise UserError(f"--expert must be one of {', '.join(EXPERTS)}, got {expert!r}")
    session = plan.session(layout, expert)
    form = label_form(plan.task)
    with run_lock(session.root):
        stamp = plan.stamp(expert)
        _check_stamp(session, stamp)
        done = finished_rows(layout, plan, expert)
        if done is not None:
            return done
        store = LabelStore(session.labels, plan.seed)
        if expert == SCRIPTED:
            write_json(session.stamp, stamp)
            return label_seed(plan, session, Answers(store, form, plan.seed))
        title = f"{plan.key.method} {plan.key.setting}, seed {plan.seed} ({plan.task.name})"
        overview = overview_of(plan.task)
        recorder = None if overview is None else OverviewRecorder(overview)
        caption = None if overview is None else overview.caption
        desk = Desk(store, form, seed=plan.seed, rounds=plan.rounds, title=title, overview=caption)
        page = PageServer(desk, port=port)  # a port in use is one line before the session begins
        write_json(session.stamp, stamp)
        with page as server:
            announce(server.url)
            rows = label_seed(plan, session, Answers(store, form, plan.seed, desk, recorder), desk)
            last = rows[-1]
            outcome = "succeeded" if last["success"] else "failed"
            desk.finish(
                f"done: {len(rows)} rounds, {last['expert_queries']} queries; the last rollout {outcome}. The command "
                f"has ended: `metadagger report --out {layout.root}` shows the session"
            )
            time.sleep(LINGER)
        return rows


def _check_stamp(session: LabelSessionLayout, stamp: dict[str, Any]) -> None:
    """Check that a session begun before was made from the same inputs as ``stamp``."""
    if not session.stamp.is_file():
        return
    changes = describe_changes(read_json(session.stamp, "the session's stamp"), stamp)
    if changes:
        raise UserError(
            f"session {session.root} was begun from other inputs ({'; '.join(changes[:4])}); move that folder away "
            "to start it again, or label another seed"
        )
