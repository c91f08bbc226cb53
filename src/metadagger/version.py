"""The package version and the source revision, in a module of its own so that any layer can
record them in artifacts."""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

__version__ = "0.3.0"


@functools.lru_cache(maxsize=1)
def source_revision() -> str:
    """The git commit of the source tree this package runs from (``+dirty`` when it has
    uncommitted changes to tracked files), or "" outside a git checkout."""
    here = Path(__file__).parent

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=here, capture_output=True, text=True, timeout=10, check=False)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return ""
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", str(here)).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return head.stdout.strip() + ("+dirty" if dirty else "")
