"""The ``metadagger`` process: its console script :func:`run`, and :func:`main`, which runs the
command line (:mod:`metadagger.cli.main`) and turns what ends it into one line and an exit code.

A usage error of the command line itself (an unknown command or option, a missing option, a value
that is not a number) is one ``error: ...`` line and exit code 2, like a
:class:`~metadagger.errors.UserError`. SIGTERM and Ctrl-C are answered from the first moment: while
the command line loads (about a second of imports), by :func:`stop_while_loading`; then by
stopping the command where it is, keeping finished work.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
from typing import Any, Optional

import typer

from metadagger.cli.options import print_error
from metadagger.utils.kernels import pin_cpu_kernels

#: The shell's names of the signals the command line answers.
SIGNAL_NAMES = {signal.SIGTERM: "SIGTERM", signal.SIGINT: "Ctrl-C"}


def stop_while_loading(signum: int, frame: Any) -> None:
    """A signal before any work: one line, and the shell's exit code (143 SIGTERM, 130 Ctrl-C)."""
    sys.stderr.write(f"error: stopped by {SIGNAL_NAMES[signum]} while the command line loaded: no work had started\n")
    sys.stderr.flush()
    os._exit(128 + signum)


def run() -> None:
    """The ``metadagger`` console script: :func:`main`, with signals answered while it loads."""
    for signum in SIGNAL_NAMES:
        signal.signal(signum, stop_while_loading)
    main()


#: The signals that stopped this command (SIGTERM or SIGINT), for its last line.
_stopped_by: list[int] = []


def _stop(signum: int, frame: Any) -> None:
    """SIGTERM and Ctrl-C stop the command where it is, as a KeyboardInterrupt: workers are
    cancelled and temporary files removed on the way out; finished work stays."""
    _stopped_by.append(signum)
    raise KeyboardInterrupt


def main(argv: Optional[list[str]] = None) -> None:
    """Run the command line on ``argv`` (default: the process's arguments) and exit with its code
    (the module docstring says how usage errors and signals end it)."""
    pin_cpu_kernels()  # first thing: the command line's kernels, before any tensor operation

    from metadagger.cli.main import app  # loaded here, under run()'s handlers

    # Click's exceptions, from wherever this Typer takes them (Click itself, or its own copy)
    click_errors = importlib.import_module(typer.BadParameter.__module__)
    # A pool stopped by a signal while it starts can leave its queues' semaphores to the
    # multiprocessing resource tracker, which removes them at exit and warns; the tracker is a
    # process of its own, started with this process's -W options: it removes them without a word.
    sys.warnoptions.append("ignore:resource_tracker:UserWarning")
    for signum in SIGNAL_NAMES:
        signal.signal(signum, _stop)
    try:
        code = app(args=argv, prog_name="metadagger", standalone_mode=False)  # Typer returns 130 on an interrupt
    except typer.Abort:  # a refused confirmation
        typer.echo("Aborted!", err=True)
        sys.exit(1)
    except getattr(click_errors, "NoArgsIsHelpError", ()):
        sys.exit(2)  # building the error printed the help
    except click_errors.ClickException as exc:  # a UsageError (exit code 2) names its command
        message = " ".join(exc.format_message().split())
        ctx = getattr(exc, "ctx", None)
        if ctx is not None:
            message += f"{'' if message.endswith(('.', '?')) else '.'} See `{ctx.command_path} --help` for the usage."
        print_error(message)
        sys.exit(exc.exit_code)
    if _stopped_by:
        print_error(
            f"stopped by {SIGNAL_NAMES[_stopped_by[0]]}: finished work is kept; run the same command again to resume "
            "where it stopped"
        )
        sys.exit(128 + _stopped_by[0])  # the shell's convention: 143 for SIGTERM, 130 for Ctrl-C
    sys.exit(code if isinstance(code, int) else 0)
