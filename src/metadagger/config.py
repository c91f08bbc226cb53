"""Configuration: frozen dataclasses built from YAML presets, validated on construction.

Presets live in ``metadagger/configs/<task>.yaml`` under ``presets: {quick, paper, ci}``, or in a
YAML file of your own with the same layout (``--presets FILE``); each preset has one section per
pipeline stage. :func:`build` turns a mapping into a (nested) frozen
dataclass and reports unknown or mistyped keys as one clear :class:`UserError` line.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import yaml

from metadagger.errors import UserError

T = TypeVar("T")
PRESETS = ("quick", "paper", "ci")


def parse_seeds(text: str | int | typing.Sequence[int]) -> tuple[int, ...]:
    """Parse ``"0-99"`` (inclusive range), ``"1,5,9"``, ``"3"`` or a list into a tuple of seeds."""
    if isinstance(text, int):
        return (text,)
    if not isinstance(text, str):
        return tuple(int(s) for s in text)
    seeds: list[int] = []
    for part in text.replace(" ", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m or (m.group(2) is not None and int(m.group(2)) < int(m.group(1))):
            raise UserError(f"bad seed list {text!r}: expected ranges like '0-99' or lists like '1,5,9' (non-negative, A <= B)")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        seeds.extend(range(lo, hi + 1))
    if len(set(seeds)) != len(seeds):
        raise UserError(f"bad seed list {text!r}: a seed appears twice; list each seed once")
    return tuple(seeds)


def load_preset(task: str, preset: str, presets_file: str | Path | None = None) -> dict[str, Any]:
    """The raw mapping of one preset: from the task's packaged YAML file, or from ``presets_file``
    (a YAML file of the same layout, ``presets: {name: {section: ...}}``, any preset names)."""
    from metadagger.tasks import check_task  # tasks import this module's helpers

    check_task(task)
    if presets_file is None:
        if preset not in PRESETS:
            raise UserError(f"unknown preset {preset!r}: expected one of {', '.join(PRESETS)}")
        try:
            text = resources.files("metadagger.configs").joinpath(f"{task}.yaml").read_text()
        except FileNotFoundError:
            raise UserError(f"task {task!r} has no packaged presets: pass --presets FILE (see docs/custom_task.md)") from None
        where = f"metadagger/configs/{task}.yaml"
    else:
        try:
            text = Path(presets_file).read_text()
        except OSError as exc:
            raise UserError(f"cannot read presets file {presets_file} ({exc.strerror}); pass an existing YAML file") from None
        where = str(presets_file)
    try:
        presets = yaml.safe_load(text).get("presets")
    except (yaml.YAMLError, AttributeError):
        presets = None
    if not isinstance(presets, dict):
        raise UserError(f"{where} must be YAML with a top-level 'presets:' mapping of preset names to stage sections")
    if preset not in presets:
        raise UserError(f"{where} has no preset {preset!r}: expected one of {', '.join(sorted(presets))}")
    return presets[preset]


def build(cls: type[T], data: typing.Mapping[str, Any], *, where: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, recursing into nested dataclass fields.

    Unknown keys and values of the wrong type raise :class:`UserError` naming the key.
    """
    where = where or cls.__name__
    if not isinstance(data, typing.Mapping):
        raise UserError(f"{where}: expected a mapping of fields, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise UserError(f"{where}: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(fields)}")
    kwargs = {name: _coerce(hints[name], value, f"{where}.{name}") for name, value in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise UserError(f"{where}: {exc}") from None


def _coerce(hint: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return value if isinstance(value, hint) else build(hint, value, where=where)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None:
            return None
        return _coerce(args[0], value, where) if len(args) == 1 else value
    if origin is tuple:
        if isinstance(value, (str, int)) and typing.get_args(hint)[:1] == (int,):
            return parse_seeds(value)
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(hint)
        inner = args[0] if args else Any
        return tuple(_coerce(inner, v, where) for v in value)
    if hint is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if hint in (int, float, str, bool) and not isinstance(value, hint) or (hint is int and isinstance(value, bool)):
        raise UserError(f"{where}: expected {hint.__name__}, got {value!r}")
    return value


#: Metadata of a config field added after runs were made with its default behaviour: stamps leave
#: it out while it holds its default, so adding it keeps every earlier artifact current.
LATER_OPTION = {"stamp": "unless_default"}


def to_dict(obj: Any, *, stamp: bool = False) -> Any:
    """A dataclass as plain YAML-ready data (tuples become lists); with ``stamp``, without the
    :data:`LATER_OPTION` fields that hold their default."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name), stamp=stamp) for f in dataclasses.fields(obj)
                if not (stamp and f.metadata.get("stamp") == "unless_default" and getattr(obj, f.name) == f.default)}
    if isinstance(obj, typing.Mapping):
        return {k: to_dict(v, stamp=stamp) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v, stamp=stamp) for v in obj]
    return obj


def dump_yaml(obj: Any) -> str:
    """A dataclass (or mapping) as YAML text."""
    return yaml.safe_dump(to_dict(obj), sort_keys=False)


def check_positive(owner: str, **values: float) -> None:
    """Raise :class:`UserError` naming the field if any value is not > 0."""
    for name, value in values.items():
        if not value > 0:
            raise UserError(f"{owner}.{name} must be > 0, got {value!r}")

