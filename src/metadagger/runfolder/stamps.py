"""What an artifact was made from: plain data that is compared, never trusted blindly.

Every stage records, beside its artifacts, the config fields and input fingerprints it ran with
(its *stamp*). A later run compares its own stamp with the recorded one: equal means the artifact
can be reused; different means it is stale, and :func:`describe_changes` names the fields that
differ (``pairs.dagger_rounds: 3 -> 4``, ``pistar: changed``).
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any, Mapping

from metadagger.utils.yaml_config import to_dict


def file_fingerprint(path: str | Path) -> str:
    """A short content hash of a file (16 hex digits of its SHA-256)."""
    path = Path(path)
    stat = path.stat()
    return _file_fingerprint(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=64)
def _file_fingerprint(path: str, mtime_ns: int, size: int) -> str:
    # keyed by mtime and size too, so a rewritten file is hashed again
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:16]


def data_fingerprint(*parts: Any) -> str:
    """A short hash of JSON-able data and byte strings (16 hex digits)."""
    digest = hashlib.sha256()
    for part in parts:
        digest.update(part if isinstance(part, bytes) else canonical(part).encode())
    return digest.hexdigest()[:16]


def canonical(data: Any) -> str:
    """Data (dataclasses included) as sorted, compact JSON: equal data gives equal text."""
    return json.dumps(to_dict(data), sort_keys=True, separators=(",", ":"))


def stamp_of(config: Any, *, drop: tuple[str, ...] = ()) -> dict[str, Any]:
    """A config dataclass as a stamp: its fields as plain data, without ``drop`` (the fields that
    only widen the work, such as seed lists and method lists)."""
    return {k: v for k, v in to_dict(config, stamp=True).items() if k not in drop}


def describe_changes(old: Mapping[str, Any], new: Mapping[str, Any], *, prefix: str = "") -> list[str]:
    """The fields whose values differ between two stamps, as ``name: old -> new`` (nested fields
    joined with dots; a ``*_fingerprint`` field reported as ``name: changed``; a field one stamp
    leaves out, as stamps do with a field stamped unless default, as ``(default)``)."""
    changes = []
    for key in sorted(set(old) | set(new)):
        name = f"{prefix}{key}"
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            changes += describe_changes(a, b, prefix=f"{name}.")
        elif key.endswith("_fingerprint"):
            changes.append(
                f"{name.removesuffix('_fingerprint')}: {'changed' if a and b else 'missing' if not b else 'new'}"
            )
        elif isinstance(a, list) and isinstance(b, list) and not (_integers(a) and _integers(b)):
            changes.append(f"{name}: {_list_change(a, b)}")
        else:
            changes.append(f"{name}: {_short(old, key)} -> {_short(new, key)}")
    return changes


def _short(stamp: Mapping[str, Any], key: str) -> str:
    if key not in stamp:
        return "(default)"
    value = stamp[key]
    text = _ranges(value) if _integers(value) and value else json.dumps(value) if value is not None else "none"
    return text if len(text) <= 40 else text[:37] + "..."


def _integers(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)


def _ranges(values: list[int]) -> str:
    """A list of integers as seed lists are written: ``[5000, ..., 5039, 7]`` -> ``5000-5039,7``."""
    runs: list[list[int]] = []
    for v in values:
        if runs and v == runs[-1][1] + 1:
            runs[-1][1] = v
        else:
            runs.append([v, v])
    return ",".join(str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in runs)


def _list_change(old: list[Any], new: list[Any], most: int = 4) -> str:
    """How a list setting changed: the items added and removed (the first ``most`` of each), or that
    only their order did."""

    def some(items: list[Any]) -> str:
        shown = ", ".join(json.dumps(item) for item in items[:most])
        return shown + (f" and {len(items) - most} more" if len(items) > most else "")

    added, removed = [v for v in new if v not in old], [v for v in old if v not in new]
    parts = ([f"added {some(added)}"] if added else []) + ([f"removed {some(removed)}"] if removed else [])
    return "; ".join(parts) if parts else "reordered"
