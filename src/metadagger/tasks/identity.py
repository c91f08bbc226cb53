"""What a task is, for the stamps of the artifacts made with it: its name, its episode length and a
fingerprint of its code.

The code fingerprint hashes the source files of every class in the task's class hierarchy (the
module's whole folder when it is part of a package, so an env or expert module beside the task's
counts too) and the versions of the distributions those modules come from. Editing the task's
code, or installing another version of its package, makes every artifact made with it stale.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import sys
from importlib.metadata import packages_distributions, version
from pathlib import Path
from typing import Any

from metadagger.tasks.base import Task


def task_stamp(task: Task) -> dict[str, Any]:
    """The task's part of a stage's stamp: ``task``, ``max_episode_steps``, ``task_code_fingerprint``,
    and ``task_options`` where the task is a variant (:attr:`Task.options`)."""
    options = {"task_options": dict(task.options)} if task.options else {}
    return {
        "task": task.name,
        "max_episode_steps": task.max_episode_steps,
        **options,
        "task_code_fingerprint": code_fingerprint(type(task)),
    }


@functools.lru_cache(maxsize=32)
def code_fingerprint(cls: type) -> str:
    """16 hex digits of SHA-256 over the source files and distribution versions behind ``cls``."""
    digest = hashlib.sha256()
    for name, data in sorted(_sources(cls).items()):
        digest.update(f"{name}\0{len(data)}\0".encode())
        digest.update(data)
    for dist in sorted(_distributions(cls)):
        digest.update(f"{dist}=={_version(dist)}\0".encode())
    return digest.hexdigest()[:16]


def _modules(cls: type) -> set[str]:
    return {klass.__module__ for klass in cls.__mro__ if klass.__module__ not in ("builtins", "abc", "typing")}


def _sources(cls: type) -> dict[str, bytes]:
    """Module-relative file name -> bytes of every source file the class hierarchy lives in."""
    files: dict[str, bytes] = {}
    for module_name in _modules(cls):
        module = sys.modules.get(module_name)
        try:
            path = Path(inspect.getfile(module)) if module is not None else None
        except TypeError:  # a module without a file (built in, or made at runtime)
            path = None
        if path is None or path.suffix != ".py":
            continue
        package = module_name.rpartition(".")[0]
        siblings = sorted(path.parent.glob("*.py")) if package else [path]
        for file in siblings:
            key = f"{package}.{file.stem}" if package else file.stem
            files[key] = file.read_bytes()
    return files


def _distributions(cls: type) -> set[str]:
    owners = packages_distributions()
    return {dist for module in _modules(cls) for dist in owners.get(module.partition(".")[0], ())}


def _version(dist: str) -> str:
    try:
        return version(dist)
    except Exception:  # metadata that cannot be read counts as no version
        return "?"
