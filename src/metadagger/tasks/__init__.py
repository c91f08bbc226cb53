"""Task registry: ``make_task(name)`` returns a :class:`~metadagger.tasks.base.Task`."""

from __future__ import annotations

import importlib
from typing import Callable

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv, Task

_FACTORIES: dict[str, Callable[[], Task] | str] = {
    "carracing": "metadagger.tasks.carracing:CarRacingTask",
    "fetch": "metadagger.tasks.fetch:FetchTask",
}


def register_task(name: str, factory: Callable[[], Task]) -> None:
    """Make ``make_task(name)`` (and ``--task name`` on the CLI) build a task with ``factory``."""
    _FACTORIES[name] = factory


def available_tasks() -> list[str]:
    """Names accepted by :func:`make_task`."""
    return sorted(_FACTORIES)


def make_task(name: str, **kwargs) -> Task:
    """Build the task called ``name``; an unknown name raises a :class:`UserError`."""
    factory = _FACTORIES.get(name)
    if factory is None:
        raise UserError(f"unknown task {name!r}: expected one of {', '.join(available_tasks())}; pass --task with one of these")
    if isinstance(factory, str):
        module, attr = factory.split(":")
        try:
            factory = getattr(importlib.import_module(module), attr)
        except ImportError as exc:
            raise UserError(
                f"task {name!r} needs a missing dependency ({exc.name}); install it with pip install 'metadagger[{name}]'"
            ) from None
    return factory(**kwargs)


__all__ = ["LearnerEnv", "Task", "available_tasks", "make_task", "register_task"]
