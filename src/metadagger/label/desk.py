"""What the labelling page and the DAgger loop share: the states a round asks, the one shown now, the clock.

The loop (the command's main thread) hands a round's asked states to :meth:`Desk.ask` and waits;
the page (the server's thread) reads :meth:`Desk.view`, which names the first state not yet
answered, in step order, and fetches its frame (:meth:`Desk.frame`), which starts the state's
clock; :meth:`Desk.answer` checks a label, keeps it on disk, and names the next state. When the
round's last label is kept, :meth:`Desk.ask` returns and the loop refits. The scripted expert's
labels, which the rollout carries, are never read here.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from metadagger.evaluation.benchmark.ledger import PERSON, label_record
from metadagger.imitation.rollouts import Trajectory
from metadagger.label.forms import LabelForm, Refused
from metadagger.label.store import LabelStore

#: How many steps either side of the shown state the page may fetch (the steps around it, on demand).
NEIGHBOURS = 8
#: Frames of the learner's last rollout in the page's clip (spread evenly over the episode).
CLIP_FRAMES = 40


@dataclass
class _Round:
    """A round's asked states while the page answers them."""

    index: int
    rollout: Trajectory
    asked: frozenset[int]
    waiting: list[int]
    """Asked steps not answered yet, in step order: the first is the one shown."""
    shown_at: float | None = None
    """When the first waiting state was first shown (the clock's time)."""


@dataclass
class _Progress:
    """Where the loop is, as the page shows it."""

    message: str = "starting: the demonstration, BC and its rollout"
    round: int = 0
    queries: int = 0
    rollout: Trajectory | None = None
    clip_id: int = 0
    done: bool = False
    paused_at: float | None = None


class Desk:
    """The state the loop and the page share; every method is safe to call from either thread.

    Args:
        store: the session's labels (each answer is kept there before it counts).
        form: how a person labels a state.
        seed: the session's seed.
        rounds: the session's rounds R.
        title: how the page names the session (method, setting, seed).
        clock: seconds, monotonic (a test may pass its own).
    """

    def __init__(
        self,
        store: LabelStore,
        form: LabelForm,
        *,
        seed: int,
        rounds: int,
        title: str,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.store, self.form, self.seed, self.rounds, self.title = store, form, seed, rounds, title
        self._clock = clock
        self._cond = threading.Condition()
        self._round: _Round | None = None
        self._progress = _Progress()

    # --- the loop's side ------------------------------------------------------------------------

    def working(
        self, message: str, *, round: int | None = None, queries: int | None = None, rollout: Trajectory | None = None
    ) -> None:
        """Say what the loop does now; where given, the rounds finished, the queries so far (the
        demonstration's included) and the learner's latest rollout (the page's clip)."""
        with self._cond:
            p = self._progress
            p.message = message
            p.round = p.round if round is None else round
            p.queries = p.queries if queries is None else queries
            if rollout is not None and rollout is not p.rollout:
                p.rollout, p.clip_id = rollout, p.clip_id + 1

    def ask(self, index: int, rollout: Trajectory, asked: np.ndarray, waiting: list[int]) -> None:
        """Show round ``index``'s ``waiting`` steps of ``rollout`` (those of ``asked`` not answered yet)
        one at a time, and return when the last is answered (a Ctrl-C or SIGTERM stops the wait)."""
        with self._cond:
            self._round = _Round(index, rollout, frozenset(int(s) for s in asked), sorted(waiting))
            self.working(f"round {index}: label the states the gate chose", rollout=rollout)
            while self._round.waiting:
                self._cond.wait(timeout=0.5)  # a timeout, so that a signal reaches the main thread
            self._progress.queries += len(self._round.asked)
            self._round = None

    def finish(self, message: str) -> None:
        """The session is over: the page says ``message`` and asks nothing more."""
        with self._cond:
            self._progress.message, self._progress.done = message, True

    # --- the page's side ------------------------------------------------------------------------

    def view(self) -> dict[str, Any]:
        """What the page shows now: where the loop is, and the state asked now, if any."""
        with self._cond:
            p, r = self._progress, self._round
            state = None
            if r is not None and r.waiting:
                state = {"round": r.index, "step": r.waiting[0], "steps": r.rollout.steps, "neighbours": NEIGHBOURS}
            answered = 0 if r is None else len(r.asked) - len(r.waiting)
            rollout = p.rollout
            return {
                "title": self.title,
                "status": "done"
                if p.done
                else "paused"
                if p.paused_at is not None
                else "asking"
                if state
                else "working",
                "message": p.message,
                "round": r.index if r is not None else p.round,
                "rounds": self.rounds,
                "queries": p.queries + answered,
                "asked": 0 if r is None else len(r.asked),
                "answered": answered,
                "state": state,
                "form": self.form.as_json(),
                "clip": None
                if rollout is None
                else {
                    "id": p.clip_id,
                    "frames": len(_clip_steps(rollout.steps)),
                    "steps": rollout.steps,
                    "success": bool(rollout.success),
                    "reward": round(float(rollout.reward), 1),
                },
            }

    def answer(self, round: int, step: int, value: Any) -> dict[str, Any]:
        """Keep a person's ``value`` for ``step`` of ``round`` (the state shown now) and show the next;
        the new view. A label for a state not shown, given twice, or out of range is :class:`Refused`
        and nothing is written."""
        with self._cond:
            r = self._round
            if r is None or round != r.index:
                raise Refused(f"round {round} step {step} is not asked now; reload the page", status=409)
            if step not in r.waiting:
                if step in r.asked:
                    raise Refused(f"round {round} step {step} is labelled already: a label is given once", status=409)
                raise Refused(f"round {round} step {step} was not asked: the gate chose other states", status=409)
            if step != r.waiting[0] or r.shown_at is None:
                raise Refused(f"round {round} step {step} is not the state shown now; reload the page", status=409)
            if self._progress.paused_at is not None:
                raise Refused("the session is paused: press Space to go on", status=409)
            label = self.form.check(value)
            switch = step - 1 not in r.asked
            self.store.add(label_record(self.seed, round, step, label, self._clock() - r.shown_at, PERSON, switch))
            r.waiting.pop(0)
            r.shown_at = None
            self._cond.notify_all()
        return self.view()

    def pause(self, paused: bool) -> dict[str, Any]:
        """Stop (``paused``) or restart the clock of the state shown; a paused page shows no state."""
        with self._cond:
            p, r = self._progress, self._round
            now = self._clock()
            if paused and p.paused_at is None:
                p.paused_at = now
            elif not paused and p.paused_at is not None:
                if r is not None and r.waiting:
                    # the pause is no labelling time; a state first served while paused is shown now
                    r.shown_at = now if r.shown_at is None else r.shown_at + now - p.paused_at
                p.paused_at = None
        return self.view()

    def frame(self, round: int, step: int) -> np.ndarray:
        """The image of ``step`` of ``round``'s rollout: the state asked now (its first serving
        starts the state's clock) or one of the :data:`NEIGHBOURS` steps either side of it; any
        other is :class:`Refused`."""
        with self._cond:
            r = self._round
            if r is None or round != r.index or not r.waiting or abs(step - r.waiting[0]) > NEIGHBOURS:
                raise Refused(
                    f"the frame of round {round} step {step} is not served: only the state shown now and the "
                    f"{NEIGHBOURS} steps either side of it",
                    status=404,
                )
            if not 0 <= step < r.rollout.steps:
                raise Refused(f"round {round} has steps 0 to {r.rollout.steps - 1}, not {step}", status=404)
            if step == r.waiting[0] and r.shown_at is None and self._progress.paused_at is None:
                r.shown_at = self._clock()  # the state is shown: its clock starts
            return r.rollout.obs[step]

    def clip(self) -> list[np.ndarray]:
        """The frames of the learner's last rollout the page plays (at most :data:`CLIP_FRAMES`)."""
        with self._cond:
            rollout = self._progress.rollout
            if rollout is None:
                raise Refused("no rollout yet: the loop is still starting", status=404)
            return [rollout.obs[i] for i in _clip_steps(rollout.steps)]


def _clip_steps(steps: int) -> list[int]:
    """At most :data:`CLIP_FRAMES` steps spread evenly over an episode of ``steps`` steps."""
    return sorted({int(i) for i in np.linspace(0, steps - 1, min(steps, CLIP_FRAMES))})
