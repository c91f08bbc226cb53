"""Progress of long loops: redrawn bars on a terminal, a few plain lines anywhere else.

A log file, ``nohup`` or CI cannot show a redrawn bar: there a bar becomes thousands of lines.
When standard error is not a terminal, :func:`progress_bar` instead prints one line when the
outermost loop reaches each quarter (each item, for ten items or fewer), with the elapsed time and
the loop's last postfix (a loss, say); loops nested inside it print nothing.
"""

from __future__ import annotations

import math
import sys
import time
from typing import IO, Any, Iterable, Iterator

from tqdm.auto import tqdm

#: Loops in lines mode running right now in this process (only the outermost one prints).
_open_loops = 0


class _Lines:
    """An iterable that prints a line at each milestone of the outermost loop (see the module)."""

    def __init__(self, iterable: Iterable[Any], *, desc: str, total: int | None, stream: IO[str]):
        self.iterable = iterable
        self.desc = desc
        self.total = total if total is not None else _length(iterable)
        self.stream = stream
        self.postfix = ""

    def set_postfix(self, refresh: bool = True, **values: Any) -> None:
        """Remember ``values`` for the next milestone's line (the signature of tqdm's)."""
        self.postfix = ", ".join(f"{k}={v}" for k, v in values.items())

    def __iter__(self) -> Iterator[Any]:
        global _open_loops
        outermost = _open_loops == 0
        _open_loops += 1
        started, done = time.monotonic(), 0
        try:
            for item in self.iterable:
                yield item
                done += 1
                if outermost and done in self._milestones():
                    self._print(done, time.monotonic() - started)
        finally:
            _open_loops -= 1

    def _milestones(self) -> set[int]:
        if self.total is None:
            return set()
        if self.total <= 10:
            return set(range(1, self.total + 1))
        return {math.ceil(self.total * quarter / 4) for quarter in (1, 2, 3, 4)}

    def _print(self, done: int, elapsed: float) -> None:
        line = f"{self.desc}: {done}/{self.total} in {clock(elapsed)}"
        if done < self.total:
            line += f", about {clock(elapsed / done * (self.total - done))} left"
        if self.postfix:
            line += f" ({self.postfix})"
        print(line, file=self.stream, flush=True)


def _length(iterable: Iterable[Any]) -> int | None:
    try:
        return len(iterable)  # type: ignore[arg-type]
    except TypeError:
        return None


def clock(seconds: float) -> str:
    """``4m05s`` or ``12s``: a duration as the progress lines write it."""
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


def progress_bar(
    iterable: Iterable[Any],
    *,
    desc: str,
    total: int | None = None,
    enabled: bool = True,
    leave: bool = True,
    stream: IO[str] | None = None,
) -> Iterable[Any]:
    """``iterable`` with its progress shown on ``stream`` (standard error by default).

    Args:
        iterable: what to loop over.
        desc: the loop's name, shown first on its bar or lines.
        total: the number of items, where ``len(iterable)`` cannot tell.
        enabled: False shows nothing.
        leave: on a terminal, keep the finished bar on screen.
        stream: where to write; a terminal gets a tqdm bar, anything else milestone lines.

    Returns:
        An iterable of the same items, with a ``set_postfix(**values)`` method.
    """
    stream = stream if stream is not None else sys.stderr
    if enabled and not stream.isatty():
        return _Lines(iterable, desc=desc, total=total, stream=stream)
    return tqdm(iterable, desc=desc, total=total, disable=not enabled, leave=leave, file=stream)


def note(line: str, *, enabled: bool = True, stream: IO[str] | None = None) -> None:
    """Print one line of progress (a milestone inside a loop, say) on ``stream`` (standard error
    by default) without breaking a bar drawn there; ``enabled=False`` prints nothing."""
    if enabled:
        tqdm.write(line, file=stream if stream is not None else sys.stderr)
