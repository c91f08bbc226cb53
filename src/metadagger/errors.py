"""User-facing errors.

A :class:`UserError` is a mistake the user can fix (bad config value, unknown task, missing or
corrupt checkpoint, wrong shapes). The CLI prints its message as one line and exits non-zero,
without a traceback. Every message says what was wrong, what was expected and how to fix it.
"""

from __future__ import annotations

import math


class UserError(ValueError):
    """An error caused by user input; its message is a complete, one-line explanation."""


class CheckpointError(UserError):
    """A checkpoint file is missing, truncated, or does not match what was expected."""


class DivergedError(UserError):
    """A fit's loss or weights became non-finite (NaN or infinite): nothing of it is kept."""


def check_finite_loss(loss: float, *, called: str, epoch: int, epochs: int, fix: str) -> None:
    """Raise :class:`DivergedError` naming the fit, the epoch and the fix if ``loss`` is not finite."""
    if not math.isfinite(loss):
        raise DivergedError(f"{called} diverged at epoch {epoch} of {epochs} (mean training loss {loss}); {fix}")
