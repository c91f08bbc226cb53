"""Early stopping of a whole-policy fit on held-out seeds: the fit's checkpoints are compared by
their success on seeds the fit never trains on, and the best one is kept.

Used for pi* (:class:`~metadagger.metal_dagger.pistar.PiStarConfig.select_seeds`), whose fit's
last epoch is not always its best: measured on Fetch, one fit's success on 80 held-out layouts
swung between 49% and 78% from one check to the next after its 12th epoch (docs/fetch.md).
"""

from __future__ import annotations

import copy
from typing import Any, Sequence

from metadagger.errors import UserError
from metadagger.imitation.episodes import evaluate_policy
from metadagger.policies import Policy
from metadagger.tasks.base import Task
from metadagger.utils.progress import note


class EpochSelector:
    """Called after every epoch of a fit (``fit_bc(..., on_epoch=selector)``): every ``every``
    epochs and after the last, rolls ``policy`` out on ``seeds`` and keeps a copy of its weights
    when it succeeds on at least as many of them as the best so far (so a tie goes to the later
    epoch, the more fitted one). :meth:`restore` then loads the kept weights; :attr:`choice`
    says which they are.

    Args:
        task: the task the rollouts run in.
        policy: the policy being fitted (read, never changed, until :meth:`restore`).
        seeds: held-out seeds, none of the fit's own.
        every: epochs between checks.
        epochs: the fit's epoch count (its last epoch is always checked).
        workers: processes the rollouts run in.
        lanes: episodes stepped in lockstep (:func:`~metadagger.imitation.collect.collect`).
        progress: print a line after each check.
    """

    def __init__(
        self,
        task: Task,
        policy: Policy,
        seeds: Sequence[int],
        *,
        every: int,
        epochs: int,
        workers: int = 1,
        lanes: int = 1,
        progress: bool = False,
    ) -> None:
        if not seeds:
            raise UserError("an EpochSelector needs at least one held-out seed")
        if every < 1:
            raise UserError(f"the selection's check interval must be >= 1 epoch, got {every}")
        self.task, self.policy, self.seeds = task, policy, tuple(seeds)
        self.every, self.epochs, self.workers, self.lanes, self.progress = every, epochs, workers, lanes, progress
        self.history: list[dict[str, int]] = []
        self._best: tuple[int, int, dict[str, Any]] | None = None  # (successes, epoch, weights)

    def __call__(self, epoch: int) -> None:
        if epoch % self.every and epoch != self.epochs:
            return
        rows = evaluate_policy(
            self.task, self.policy, self.seeds, progress=False, workers=self.workers, lanes=self.lanes
        )
        wins = sum(bool(row["success"]) for row in rows)
        self.history.append({"epoch": epoch, "successes": wins, "episodes": len(rows)})
        if self._best is None or wins >= self._best[0]:
            self._best = (wins, epoch, copy.deepcopy(self.policy.net.state_dict()))
        note(
            f"epoch {epoch}: {wins}/{len(rows)} held-out seeds (best: epoch {self._best[1]}, {self._best[0]})",
            enabled=self.progress,
        )

    @property
    def choice(self) -> dict[str, Any]:
        """``{"epoch": the best epoch, "successes": its count, "episodes": seeds checked,
        "history": every check}``."""
        wins, epoch, _ = self._checked_best()
        return {"epoch": epoch, "successes": wins, "episodes": len(self.seeds), "history": list(self.history)}

    def restore(self) -> None:
        """Load the best checkpoint's weights into the policy."""
        self.policy.net.load_state_dict(self._checked_best()[2])

    def _checked_best(self) -> tuple[int, int, dict[str, Any]]:
        if self._best is None:
            raise UserError("no epoch was checked: call the selector after the fit's epochs first")
        return self._best
