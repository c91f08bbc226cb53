"""Which metadagger version made a run folder, and the one line that refuses a folder of another one.

A run folder's ``config.yaml`` records the version that made it (:data:`VERSION_KEY`). A folder of
another major.minor version (its sections, method names and stamps may differ: ``groundtruth``
before ``pistar``, say) is refused by every command that reads it, stages and report alike, with
one line saying what to do; a patch version reads as its own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from metadagger.errors import UserError
from metadagger.version import __version__

VERSION_KEY = "metadagger_version"
"""The config key that records the metadagger version a run folder was made by."""
FIRST_RECORDED = "0.2"
"""The first version whose run folders record it: a ``config.yaml`` without it is older."""


def check_version(path: str | Path, data: dict[str, Any]) -> None:
    """Raise a :class:`UserError` unless the run config ``data`` (read from ``path``) was made by a
    metadagger of this major.minor version; a folder of another one needs that version's code."""
    recorded = data.get(VERSION_KEY)
    if recorded is not None and _major_minor(str(recorded)) == _major_minor(__version__):
        return
    made_by = f"metadagger {recorded}" if recorded is not None else f"a metadagger version before {FIRST_RECORDED}"
    task, preset = data.get("task", "T"), data.get("preset", "P")
    raise UserError(
        f"{path} was made by {made_by}; this is {__version__}: start a new run folder "
        f"(metadagger reproduce --task {task} --preset {preset} --out NEW) or use {made_by}"
    )


def _major_minor(version: str) -> tuple[str, ...]:
    return tuple(version.split(".")[:2])
