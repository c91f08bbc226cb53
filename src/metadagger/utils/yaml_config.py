"""Configuration: frozen dataclasses built from YAML, validated on construction.

The presets they are built from (:func:`metadagger.pipeline.run_config.load_preset`) live in
``metadagger/pipeline/presets/<task>.yaml``, or in a YAML file of your own with the same layout
(``--presets FILE``). :func:`build` turns a mapping into a (nested) frozen
dataclass and reports unknown or mistyped keys as one clear :class:`UserError` line.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections import Counter
from pathlib import Path
from typing import Any, TypeVar

import yaml

from metadagger.errors import UserError

T = TypeVar("T")
SEED_FIELD = re.compile(r"(\w+_)?seed")
"""Names of the int config fields that hold a seed (``seed``, ``split_seed``)."""
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
SEEDS_FIELD = re.compile(r"(\w+_)?seeds")
"""Names of the tuple-of-int config fields that hold seeds (``seeds``, ``eval_seeds``); a string
value is a seed list (:func:`parse_seeds`)."""


#: The largest seed (env seeds go to ``reset(seed=...)`` and generators as 32-bit numbers).
MAX_SEED = 2**32 - 1
#: The most seeds one list may hold (checked before a range is expanded).
MAX_SEEDS = 1_000_000
#: The largest value of any other integer setting (epochs, rounds, sizes, counts).
MAX_COUNT = 10**9


def parse_seeds(text: str | int | typing.Sequence[int]) -> tuple[int, ...]:
    """Parse ``"0-99"`` (inclusive range), ``"1,5,9"``, ``"3"`` or a list into a tuple of seeds.

    Seeds lie in ``[0, MAX_SEED]`` and a list holds at most :data:`MAX_SEEDS`, checked before
    any range is expanded."""
    if isinstance(text, int):
        return check_seeds((text,), f"bad seed list {text!r}")
    if not isinstance(text, str):
        text = list(text)
        if len(text) > MAX_SEEDS:
            raise UserError(
                f"bad seed list: {len(text)} seeds, more than the {MAX_SEEDS:,} one list may hold; give fewer seeds"
            )
        return check_seeds(tuple(int(s) for s in text), f"bad seed list {text!r}"[:120])
    parts = []
    for part in text.replace(" ", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m or (m.group(2) is not None and int(m.group(2)) < int(m.group(1))):
            raise UserError(
                f"bad seed list {text!r}: expected ranges like '0-99' or lists like '1,5,9' (non-negative, A <= B)"
            )
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi > MAX_SEED:
            raise UserError(
                f"bad seed list {text!r}: seed {hi} is above the largest seed, {MAX_SEED}; use smaller seeds"
            )
        parts.append((lo, hi))
    count = sum(hi - lo + 1 for lo, hi in parts)
    if count > MAX_SEEDS:
        raise UserError(
            f"bad seed list {text!r}: {count:,} seeds, more than the {MAX_SEEDS:,} one list may hold; "
            "give a shorter range"
        )
    return check_seeds([seed for lo, hi in parts for seed in range(lo, hi + 1)], f"bad seed list {text!r}")


def check_seeds(seeds: typing.Sequence[int], called: str) -> tuple[int, ...]:
    """``seeds`` as a tuple, checked to be in ``[0, MAX_SEED]`` and distinct (``called`` names them in the error)."""
    negative = [s for s in seeds if s < 0]
    if negative:
        raise UserError(f"{called}: seed {negative[0]} is negative; use seeds >= 0")
    large = [s for s in seeds if s > MAX_SEED]
    if large:
        raise UserError(f"{called}: seed {large[0]} is above the largest seed, {MAX_SEED}; use smaller seeds")
    repeated = [s for s, n in Counter(seeds).items() if n > 1]
    if repeated:
        raise UserError(f"{called}: seed {repeated[0]} appears twice; list each seed once")
    return tuple(seeds)


def read_yaml_mapping(path: str | Path, called: str, fix: str) -> dict[str, Any]:
    """The mapping in the YAML file ``path`` (described as ``called``); a file that cannot be read, is
    not UTF-8 text, is not valid YAML or holds no mapping is a :class:`UserError` naming it and ``fix``."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        problem = exc.strerror
    except UnicodeDecodeError as exc:
        problem = f"not UTF-8 text: byte {exc.object[exc.start]:#04x} at offset {exc.start}"
    except yaml.YAMLError as exc:
        problem = _yaml_problem(exc)
    else:
        if isinstance(data, dict):
            return data
        problem = f"expected a mapping, got {type(data).__name__}"
    raise UserError(f"{path} is not a readable YAML {called} ({problem}); {fix}")


def read_run_data(path: str | Path) -> dict[str, Any]:
    """The mapping in a run's ``config.yaml`` at ``path``, not yet validated; an unreadable file is
    a :class:`UserError` naming it."""
    return read_yaml_mapping(path, "config", "restore it or start a new run folder (--out)")


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """A YAML parser's error as one line: its problem and, when known, its line and column."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    return " ".join(f"{problem}{where}".split())


def build(cls: type[T], data: typing.Mapping[str, Any], *, where: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, recursing into nested dataclass fields.

    A nested dataclass field given as a mapping starts from that field's own default (a stage's
    ``bc`` section from the stage's BC settings, not from ``BCConfig()``), so a section names only
    what it changes. Unknown keys and values of the wrong type raise :class:`UserError` naming the key.
    """
    where = where or cls.__name__
    if not isinstance(data, typing.Mapping):
        raise UserError(f"{where}: expected a mapping of fields, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        renamed = getattr(cls, "RENAMED", {})
        hint = "".join(f" ({old} is now {renamed[old]})" for old in unknown if old in renamed)
        raise UserError(f"{where}: unknown field(s) {', '.join(unknown)}{hint}; allowed: {', '.join(fields)}")
    kwargs = {
        name: _coerce(hints[name], _over_default(fields[name], value), f"{where}.{name}", name)
        for name, value in data.items()
    }
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise UserError(f"{where}: {exc}") from None


def with_current_names(cls: type, data: typing.Mapping[str, Any]) -> dict[str, Any]:
    """``data`` for dataclass ``cls`` with every key an older version used (a class's ``RENAMED``)
    under its name now, at every depth: what a run folder's config written before a rename means
    today. A key whose new name is also given stays, for :func:`build` to refuse."""
    renamed = getattr(cls, "RENAMED", {})
    hints = typing.get_type_hints(cls)
    current: dict[str, Any] = {}
    for key, value in data.items():
        name = renamed[key] if key in renamed and renamed[key] not in data else key
        nested = _dataclass_of(hints.get(name))
        current[name] = with_current_names(nested, value) if nested and isinstance(value, typing.Mapping) else value
    return current


def _dataclass_of(hint: Any) -> type | None:
    """The dataclass a field's type ``hint`` holds (itself, or the one of an optional), else None."""
    for candidate in (hint, *typing.get_args(hint)):
        if isinstance(candidate, type) and dataclasses.is_dataclass(candidate):
            return candidate
    return None


def _over_default(field: dataclasses.Field, value: Any) -> Any:
    """``value``, a mapping of fields, laid over ``field``'s default dataclass; any other value as it is."""
    if not isinstance(value, typing.Mapping):
        return value
    return _laid_over(
        field.default_factory() if field.default_factory is not dataclasses.MISSING else field.default, value
    )


def _laid_over(default: Any, value: Any) -> Any:
    """A mapping ``value`` laid over the dataclass instance ``default``, at every depth; else ``value``."""
    if not (isinstance(value, typing.Mapping) and dataclasses.is_dataclass(default) and not isinstance(default, type)):
        return value
    merged = {f.name: getattr(default, f.name) for f in dataclasses.fields(default) if f.init}
    return {**merged, **{name: _laid_over(merged.get(name), item) for name, item in value.items()}}


def _coerce(hint: Any, value: Any, where: str, field: str = "") -> Any:
    """``value`` as type ``hint`` of config field ``field`` (at ``where``); the seeds of
    :data:`SEED_FIELD` and :data:`SEEDS_FIELD` fields are checked to be >= 0 and distinct."""
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return value if isinstance(value, hint) else build(hint, value, where=where)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None:
            return None
        return _coerce(args[0], value, where, field) if len(args) == 1 else value
    if origin is tuple:
        args = typing.get_args(hint)
        inner = args[0] if args else Any
        seed_list = inner is int and SEEDS_FIELD.fullmatch(field) is not None
        if seed_list and isinstance(value, (str, int)) and not isinstance(value, bool):
            try:
                return parse_seeds(value)
            except UserError as exc:
                raise UserError(f"{where}: {exc}") from None
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{where}: expected a list of {getattr(inner, '__name__', inner)}, got {value!r}")
        items = tuple(_coerce(inner, v, where) for v in value)
        return check_seeds(items, where) if seed_list else items
    if hint is float and isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
        value = float(value)  # YAML 1.1 reads 1e-3 (no dot) as text
    if hint is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise UserError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if (
        hint is int
        and isinstance(value, int)
        and not isinstance(value, bool)
        and not SEED_FIELD.fullmatch(field)
        and abs(value) > MAX_COUNT
    ):
        raise UserError(
            f"{where}: {value} is beyond the largest count metadagger accepts, {MAX_COUNT:,}; give a smaller value"
        )
    if hint in (int, float, str, bool) and not isinstance(value, hint) or (hint is int and isinstance(value, bool)):
        raise UserError(f"{where}: expected {hint.__name__}, got {value!r}")
    return check_seeds((value,), where)[0] if hint is int and SEED_FIELD.fullmatch(field) else value


#: Metadata of a config field added after runs were made with its default behaviour: stamps leave
#: it out while it holds its default, so adding it keeps every earlier artifact current.
STAMPED_UNLESS_DEFAULT = {"stamp": "unless_default"}


def to_dict(obj: Any, *, stamp: bool = False) -> Any:
    """A dataclass as plain YAML-ready data (tuples become lists); with ``stamp``, without the
    :data:`STAMPED_UNLESS_DEFAULT` fields that hold their default."""
    if dataclasses.is_dataclass(obj):
        return {
            f.name: to_dict(getattr(obj, f.name), stamp=stamp)
            for f in dataclasses.fields(obj)
            if not (stamp and f.metadata.get("stamp") == "unless_default" and getattr(obj, f.name) == f.default)
        }
    if isinstance(obj, typing.Mapping):
        return {k: to_dict(v, stamp=stamp) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v, stamp=stamp) for v in obj]
    return obj


def dump_yaml(obj: Any) -> str:
    """A dataclass (or mapping) as YAML text."""
    return yaml.safe_dump(to_dict(obj), sort_keys=False)
