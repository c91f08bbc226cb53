"""Task registry: ``make_task(name)`` returns a :class:`~metadagger.tasks.base.Task`.

Tasks come from three places: the built-in ones, :func:`register_task` (in your own process),
and installed packages that declare an entry point in the group ``metadagger.tasks``
(``mytask = "mypkg.tasks:MyTask"``), which the command line then knows too.
"""

from __future__ import annotations

import importlib
import inspect
from importlib.metadata import entry_points
from typing import Callable

from metadagger.errors import UserError
from metadagger.tasks.base import LearnerEnv, Task
from metadagger.tasks.gym_ids import register_envs

#: Entry-point group through which installed packages add tasks.
ENTRY_POINT_GROUP = "metadagger.tasks"

_FACTORIES: dict[str, Callable[[], Task] | str] = {
    "carracing": "metadagger.tasks.carracing.task:CarRacingTask",
    "fetch": "metadagger.tasks.fetch.task:FetchTask",
    "carracing-family": "metadagger.tasks.carracing.family:CarRacingFamily",
    "carracing-echo": "metadagger.tasks.carracing_echo.task:CarRacingEchoTask",
    "fetch-family": "metadagger.tasks.fetch.family:FetchFamily",
}


#: The pip extra that installs a built-in task's dependencies (the others need none beyond metadagger's own).
_EXTRAS = {"fetch": "fetch", "fetch-family": "fetch"}


def register_task(name: str, factory: Callable[[], Task]) -> None:
    """Make ``make_task(name)`` (and ``--task name`` on the CLI) build a task with ``factory``."""
    _FACTORIES[name] = factory


def _factories() -> dict[str, Callable[[], Task] | str]:
    """Every known task factory: installed entry points, overridden by built-in and registered ones."""
    plugins = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return {**plugins, **_FACTORIES}


def available_tasks() -> list[str]:
    """Names accepted by :func:`make_task`."""
    return sorted(_factories())


def check_task(name: str) -> None:
    """Raise a :class:`UserError` naming the known tasks unless ``name`` is one of them."""
    if name not in _factories():
        raise UserError(
            f"unknown task {name!r}: expected one of {', '.join(available_tasks())}; pass --task with one of these"
        )


def make_task(name: str, **kwargs) -> Task:
    """Build the task called ``name``; an unknown name raises a :class:`UserError`. Registers
    metadagger's Gymnasium ids (:func:`~metadagger.tasks.gym_ids.register_envs`) first."""
    register_envs()
    check_task(name)
    factory = _factories()[name]
    if isinstance(factory, str):
        factory = _load_factory(name, factory)
    try:
        inspect.signature(factory).bind(**kwargs)
    except TypeError:
        raise UserError(
            f"task {name!r} cannot be built with {kwargs}: its factory {factory!r} must accept these keyword arguments "
            "(see docs/custom_task.md)"
        ) from None
    except ValueError:  # no signature to check (a builtin): let the call tell
        pass
    return factory(**kwargs)


def _load_factory(name: str, target: str) -> Callable[..., Task]:
    """The factory that ``module:attr`` names; a missing module or attribute is a :class:`UserError`."""
    module, _, attr = target.partition(":")
    entry_point = f'the entry point {name} = "{target}" (group {ENTRY_POINT_GROUP})'
    if _FACTORIES.get(name) != target:
        fix = f"install what the package declaring {entry_point} needs, or fix that entry point"
    elif name in _EXTRAS:
        fix = f"install it with pip install 'metadagger[{_EXTRAS[name]}]'"
    else:
        fix = "reinstall metadagger with its dependencies"
    try:
        factory = importlib.import_module(module)
    except ImportError as exc:
        raise UserError(f"task {name!r} needs a missing module ({exc.name}); {fix}") from None
    for part in attr.split(".") if attr else [""]:
        if not hasattr(factory, part):
            raise UserError(
                f"task {name!r}: module {module} has no {attr!r}; fix {entry_point} to name the task's class as "
                "module:name"
            )
        factory = getattr(factory, part)
    return factory


__all__ = ["LearnerEnv", "Task", "available_tasks", "check_task", "make_task", "register_task"]
