"""Every cross-reference in the package's docstrings and comments (``:func:`...```, ``:class:``,
``:mod:``, ``:meth:``, ``:attr:``, ``:data:``, ``:exc:``) names something that exists: a
``metadagger.`` path down to its last name, a name the module defines followed by its attributes,
or a bare name of a member of one of the module's classes (a method's docstring naming its
class's own ``:meth:`step```). A rename that leaves a reference behind fails here, not in a
reader's search. Dotted names of other libraries (``torch.optim.Adam``) are not checked."""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
from pathlib import Path
from types import ModuleType
from typing import Any

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "metadagger"
REFERENCE = re.compile(r":(func|class|mod|meth|attr|data|exc):`~?([A-Za-z_][\w.]*)`")


def _module_name(path: Path) -> str:
    parts = ["metadagger", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _has(owner: Any, name: str) -> bool:
    """``owner.name`` exists: an attribute, a field or annotation of a class or its bases, or an
    attribute its code sets on ``self``."""
    if hasattr(owner, name):
        return True
    for klass in getattr(owner, "__mro__", ()):
        if name in getattr(klass, "__annotations__", {}):
            return True
        try:
            if re.search(rf"\bself\.{name}\b", inspect.getsource(klass)):
                return True
        except (OSError, TypeError):
            continue
    return False


def _resolves(path: str) -> bool:
    """Whether dotted ``path`` names an object: the longest importable module, then attributes."""
    parts = path.split(".")
    for split in range(len(parts), 0, -1):
        try:
            owner: Any = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for name in parts[split:]:
            if not _has(owner, name):
                return False
            owner = getattr(owner, name, None)
        return True
    return False


def _classes(module: ModuleType) -> list[type]:
    """The classes ``module`` defines (not those it imports)."""
    return [c for c in vars(module).values() if inspect.isclass(c) and c.__module__ == module.__name__]


def _unresolved(module: ModuleType, text: str) -> list[str]:
    found = []
    for match in REFERENCE.finditer(text):
        role, target = match[1], match[2]
        if target.startswith("metadagger."):
            ok = _resolves(target)
        elif hasattr(module, target.split(".")[0]):
            ok = _resolves(f"{module.__name__}.{target}")
        elif role == "mod":
            ok = importlib.util.find_spec(target) is not None
        elif "." not in target:
            ok = any(_has(klass, target) for klass in _classes(module))
        else:
            continue  # another library's name (torch, numpy, gymnasium): not ours to check
        if not ok:
            found.append(match[0])
    return found


def test_every_cross_reference_in_the_package_names_something_that_exists():
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__main__.py":  # importing it runs the command line
            continue
        module = importlib.import_module(_module_name(path))
        problems += [f"{path.relative_to(PACKAGE)}: {ref}" for ref in _unresolved(module, path.read_text())]
    assert not problems, "cross-references to nothing:\n" + "\n".join(problems)


def test_a_reference_to_a_moved_or_renamed_name_is_caught():
    from metadagger.imitation import bc

    assert _unresolved(bc, ":func:`fit_bc` and :class:`~metadagger.imitation.reading_gates.DisagreementGate`") == []
    assert _unresolved(bc, ":class:`ReferenceEpoch.optimizer` and :attr:`BCConfig.augment_shift`") == []
    assert _unresolved(bc, ":class:`~metadagger.imitation.gates.DisagreementGate`") == [
        ":class:`~metadagger.imitation.gates.DisagreementGate`"
    ]
    assert (
        _unresolved(bc, ":meth:`write_back` and :class:`torch.optim.Adam`") == []
    )  # a class's member; another library
    assert _unresolved(bc, ":func:`fit_bc_twice`") == [":func:`fit_bc_twice`"]  # renamed away
    assert _unresolved(bc, ":mod:`mujoco` and :mod:`metadagger`") == []
    assert _unresolved(bc, ":meth:`ReferenceEpoch.no_such_step`") == [":meth:`ReferenceEpoch.no_such_step`"]
