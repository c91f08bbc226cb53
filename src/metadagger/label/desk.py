"""What the labelling page and the DAgger loop share: the states a round asks, the one shown now, the clock.

The loop (the command's main thread) hands a round's asked states to :meth:`Desk.ask` and waits;
the page (the server's thread) reads :meth:`Desk.view`, which names the first state not yet
answered, in step order, and fetches its frame (:meth:`Desk.frame`); :meth:`Desk.answer` checks a
label, keeps it on disk, and names the next state. When the round's last label is kept,
:meth:`Desk.ask` returns and the loop refits. The scripted expert's labels, which the rollout
carries, are never read here.

A state's clock runs only while a page shows it: a page that shows the state says so every
:data:`POLL` seconds while it is visible (:meth:`Desk.showing`), and says when it hides it. The
seconds between two such words count; a pause, a hidden page, and a silence longer than
:data:`SILENCE` (a page closed, a browser or a connection lost) count nothing.
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
#: Seconds between a visible page's words that it shows the state (its polls of the view).
POLL = 0.4
#: Seconds without a word from a page after which it is taken to show the state no more: the time
#: since its last word is not counted (several polls lost in a row, not one slow answer).
SILENCE = 3.0


@dataclass
class _Round:
    """A round's asked states while the page answers them."""

    index: int
    rollout: Trajectory
    asked: frozenset[int]
    waiting: list[int]
    """Asked steps not answered yet, in step order: the first is the one shown."""
    overview: Callable[[int], np.ndarray] | None = None
    """The overview picture of a step (:mod:`~metadagger.label.overview`); None: the task has none."""
    served: bool = False
    """Whether the first waiting state's frame was served."""
    shown: bool = False
    """Whether a page said it shows the first waiting state (its frame served): a label may be given."""
    seconds: float = 0.0
    """The seconds the first waiting state was shown, up to :attr:`seen_at`."""
    seen_at: float | None = None
    """When a page last said it shows the state (the clock's time); None while no page shows it."""

    def advance(self) -> None:
        """The first waiting state is answered: the next one is shown from nothing."""
        self.waiting.pop(0)
        self.served = self.shown = False
        self.seconds, self.seen_at = 0.0, None


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
        overview: the caption of the task's overview of a state (:mod:`~metadagger.label.overview`); None: the
            task has none.
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
        overview: str | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.store, self.form, self.seed, self.rounds, self.title = store, form, seed, rounds, title
        self.overview_caption = overview
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

    def ask(
        self,
        index: int,
        rollout: Trajectory,
        asked: np.ndarray,
        waiting: list[int],
        overview: Callable[[int], np.ndarray] | None = None,
    ) -> None:
        """Show round ``index``'s ``waiting`` steps of ``rollout`` (those of ``asked`` not answered yet)
        one at a time, with ``overview``'s picture of each where given, and return when the last is
        answered (a Ctrl-C or SIGTERM stops the wait)."""
        with self._cond:
            self._round = _Round(index, rollout, frozenset(int(s) for s in asked), sorted(waiting), overview)
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
                state = {
                    "round": r.index,
                    "step": r.waiting[0],
                    "steps": r.rollout.steps,
                    "neighbours": NEIGHBOURS,
                    "overview": r.overview is not None,
                }
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
                "overview": self.overview_caption,
                "poll": POLL,
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
            if not 0 <= step < r.rollout.steps:
                raise Refused(f"round {round} has steps 0 to {r.rollout.steps - 1}, not {step}")
            if step not in r.waiting:
                if step in r.asked:
                    raise Refused(f"round {round} step {step} is labelled already: a label is given once", status=409)
                raise Refused(f"round {round} step {step} was not asked: the gate chose other states", status=409)
            if step != r.waiting[0] or not r.shown:
                raise Refused(f"round {round} step {step} is not the state shown now; reload the page", status=409)
            if self._progress.paused_at is not None:
                raise Refused("the session is paused: press Space to go on", status=409)
            label = self.form.check(value)
            switch = step - 1 not in r.asked
            self._see(r, self._clock())  # the answer is the page's last word on the state
            self.store.add(label_record(self.seed, round, step, label, r.seconds, PERSON, switch))
            r.advance()
            self._cond.notify_all()
        return self.view()

    def showing(self, state: tuple[int, int] | None) -> None:
        """A page says it shows ``state`` (round, step) now, visible; None: it shows none any more
        (hidden, closed). Only the state asked now, its frame served and the session not paused,
        runs the clock; any other word is taken as nothing."""
        with self._cond:
            r, now = self._round, self._clock()
            if r is None or not r.waiting or not r.served or self._progress.paused_at is not None:
                return
            if state is None:
                self._see(r, now)
                r.seen_at = None
            elif state == (r.index, r.waiting[0]):
                self._see(r, now)
                r.seen_at, r.shown = now, True

    @staticmethod
    def _see(r: _Round, now: float) -> None:
        """Count the seconds since a page last said it shows ``r``'s state, unless it fell silent since."""
        if r.seen_at is not None and now - r.seen_at <= SILENCE:
            r.seconds += now - r.seen_at

    def pause(self, paused: bool) -> dict[str, Any]:
        """Stop (``paused``) or restart the clock of the state shown; a paused page shows no state, and
        the page that ends the pause shows it again."""
        with self._cond:
            p, r = self._progress, self._round
            now = self._clock()
            if paused and p.paused_at is None:
                if r is not None and r.waiting:
                    self._see(r, now)
                    r.seen_at = None
                p.paused_at = now
            elif not paused and p.paused_at is not None:
                p.paused_at = None
                if r is not None and r.waiting and r.served:
                    r.seen_at, r.shown = now, True
        return self.view()

    def frame(self, round: int, step: int) -> np.ndarray:
        """The image of ``step`` of ``round``'s rollout: the state asked now or one of the
        :data:`NEIGHBOURS` steps either side of it; any other is :class:`Refused`."""
        with self._cond:
            r = self._shown_round(round, step, NEIGHBOURS)
            if step == r.waiting[0]:
                r.served = True
            return r.rollout.obs[step]

    def overview(self, round: int, step: int) -> np.ndarray:
        """The overview picture of ``step`` of ``round``, the state asked now; where the task has none,
        or for any other state, :class:`Refused`."""
        with self._cond:
            r = self._shown_round(round, step, 0)
            if r.overview is None:
                raise Refused("this task has no overview: the page shows the frame alone", status=404)
            draw = r.overview
        return draw(step)  # outside the lock: the loop's thread may ask for the view meanwhile

    def _shown_round(self, round: int, step: int, around: int) -> _Round:
        """The round asked now, where ``step`` of ``round`` is within ``around`` steps of its state
        shown and within its rollout; else :class:`Refused`."""
        r = self._round
        if r is None or round != r.index or not r.waiting or abs(step - r.waiting[0]) > around:
            what = f"the {around} steps either side of it" if around else "nothing else"
            raise Refused(f"round {round} step {step} is not served: only the state shown now and {what}", status=404)
        if not 0 <= step < r.rollout.steps:
            raise Refused(f"round {round} has steps 0 to {r.rollout.steps - 1}, not {step}", status=404)
        return r

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
