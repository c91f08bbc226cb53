"""metadagger: Meta-Learning DAgger (MetaL DAgger) for imitation-learning research.

Importing the package changes nothing in the process and loads no numerical library: the names
below load their modules when first used, so that a program can pin the CPU kernels before numpy,
OpenCV or torch load (:func:`pin_cpu_kernels`; the command line, the pipeline's entry points and
the executors' workers do it themselves). The Gymnasium ids are registered when a task or one of
its envs is made (:func:`~metadagger.tasks.gym_ids.register_envs`). The public interface::

    import metadagger
    metadagger.pin_cpu_kernels()          # first, before numpy, OpenCV or torch load
    task = metadagger.make_task("carracing")
    policy = metadagger.load_policy(path)
    mapper = metadagger.load_mapper(path)
"""

from __future__ import annotations

import importlib
from typing import Any

from metadagger.errors import CheckpointError, UserError
from metadagger.utils.kernels import pin_cpu_kernels
from metadagger.version import __version__

#: Public names and the modules that define them, imported on first use.
_LAZY = {
    "make_task": "metadagger.tasks",
    "register_task": "metadagger.tasks",
    "register_envs": "metadagger.tasks.gym_ids",
    "load_policy": "metadagger.policies",
    "load_mapper": "metadagger.mapping.mappers",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'metadagger' has no attribute {name!r}")


__all__ = [
    "CheckpointError",
    "UserError",
    "__version__",
    "load_mapper",
    "load_policy",
    "make_task",
    "pin_cpu_kernels",
    "register_envs",
    "register_task",
]
