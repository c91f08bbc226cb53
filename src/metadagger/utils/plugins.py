"""What installed packages add through entry points (gates, mapper kinds): loaded on first use,
and a broken one is one :class:`~metadagger.errors.UserError` naming its package, never a traceback."""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Mapping, TypeVar

from metadagger.errors import UserError

T = TypeVar("T")


def load_plugins(group: str, *, plugin: str, thing: str, expected: type[T], known: Mapping[str, T]) -> list[T]:
    """The objects the entry points of ``group`` name, each a ``expected`` with a ``name`` equal to
    its entry point's and not already in ``known`` (as another object).

    Args:
        group: the entry-point group, e.g. ``metadagger.gates``.
        plugin: how messages name a plug-in of the group (``gate``, ``mapper``).
        thing: how messages name what it adds (``gate``, ``mapper kind``).
        expected: the type each entry point must name.
        known: what metadagger has already, by name.
    """
    found: list[T] = []
    for ep in entry_points(group=group):
        package = ep.dist.name if ep.dist is not None else "an unknown package"
        where = f"{plugin} plug-in {ep.name!r} of package {package} ({ep.value})"
        fix = f"fix or uninstall {package}"
        try:
            obj = ep.load()
        except UserError as exc:
            raise UserError(f"{where}: {exc}; {fix}") from None
        except Exception as exc:  # a plug-in's import may fail any way: one line, never a traceback
            raise UserError(f"{where} fails to load ({type(exc).__name__}: {exc}); {fix}") from None
        if not isinstance(obj, expected):
            raise UserError(f"{where} names a {type(obj).__name__}, not a {expected.__name__}; {fix}")
        name = getattr(obj, "name")
        if name != ep.name:
            raise UserError(f"{where} declares a {thing} named {name!r}; name the entry point the same; {fix}")
        if name in known and known[name] is not obj:
            raise UserError(f"{where}: metadagger already has a {thing} called {name!r}; rename it; {fix}")
        found.append(obj)
    return found
