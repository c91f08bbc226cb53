"""User-facing errors.

A :class:`UserError` is a mistake the user can fix (bad config value, unknown task, missing or
corrupt checkpoint, wrong shapes). The CLI prints its message as one line and exits non-zero,
without a traceback. Every message says what was wrong, what was expected and how to fix it.
"""

from __future__ import annotations


class UserError(ValueError):
    """An error caused by user input; its message is a complete, one-line explanation."""


class CheckpointError(UserError):
    """A checkpoint file is missing, truncated, or does not match what was expected."""
