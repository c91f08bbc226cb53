"""The command line, the top layer: ``metadagger`` (:mod:`.main`), its demo (:mod:`.demo`) and
its benchmarks (:mod:`.bench`). ``python -m metadagger.cli`` runs the same command line.

The console script is :func:`run`: it answers SIGTERM and Ctrl-C from its first moment, while the
command line loads (about a second of imports), before :func:`metadagger.cli.main.main` takes over.
"""

from __future__ import annotations

import os
import signal
import sys
from typing import Any

#: The shell's names of the signals the command line answers.
SIGNAL_NAMES = {signal.SIGTERM: "SIGTERM", signal.SIGINT: "Ctrl-C"}


def stop_while_loading(signum: int, frame: Any) -> None:
    """A signal before any work: one line, and the shell's exit code (143 SIGTERM, 130 Ctrl-C)."""
    sys.stderr.write(f"error: stopped by {SIGNAL_NAMES[signum]} while the command line loaded: no work had started\n")
    sys.stderr.flush()
    os._exit(128 + signum)


def run() -> None:
    """The ``metadagger`` console script (see the module docstring)."""
    for signum in SIGNAL_NAMES:
        signal.signal(signum, stop_while_loading)
    from metadagger.cli.main import main

    main()
