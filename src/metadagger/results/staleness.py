"""Whether a registry run is current: made by what its canonical command makes now, with this code's
numerics.

A registry run is *current* when its ``config.yaml`` is what its canonical command's preset and
overrides resolve to today and its manifest's ``NUMERICS`` (and, where a stage rolls out in lanes,
``LANE_NUMERICS``) are this code's; otherwise it is *stale*, and :func:`run_staleness` says why as
``setting: run's -> today's``. A stale run stays in the registry: the generated blocks show its
numbers marked, and ``metadagger results status`` lists it with the command that makes it again.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import yaml

from metadagger.errors import UserError
from metadagger.imitation.lanes import LANE_NUMERICS
from metadagger.pipeline.run_config import VERSION_KEY, RunConfig, resolve_config
from metadagger.results.registry import CANONICAL_RUNS, RegistryRun, canonical_run
from metadagger.runfolder.stamps import describe_changes
from metadagger.utils.kernels import NUMERICS
from metadagger.utils.yaml_config import build, dump_yaml, read_run_data, with_current_names

#: Config keys that change no number: the package version that wrote the file, and logging.
IGNORED_KEYS = (VERSION_KEY, "log")


def run_staleness(run: RegistryRun) -> list[str]:
    """Why registry run ``run`` is stale, as ``setting: run's -> today's`` lines (``NUMERICS`` and
    ``LANE_NUMERICS`` first, then the config's sections and settings); empty for a current run."""
    canonical = canonical_run(run.name)
    made = _settings(_made_with(run))
    today = _settings(_as_data(resolve_config(canonical.task, canonical.preset, overrides=canonical.overrides)))
    numerics = run.manifest["machine"].get("numerics")
    reasons = [] if numerics == NUMERICS else [f"NUMERICS {numerics} -> {NUMERICS}"]
    lane_numerics = run.manifest.get("lane_numerics")
    if _laned(made) and lane_numerics != LANE_NUMERICS:
        recorded = lane_numerics if lane_numerics is not None else "unrecorded"
        reasons.append(f"LANE_NUMERICS {recorded} -> {LANE_NUMERICS}")
    reasons += [f"{key}: a section no longer read" for key in made if key not in today]
    reasons += [f"{key}: a section new since" for key in today if key not in made]
    shared = [key for key in made if key in today]
    reasons += describe_changes({k: made[k] for k in shared}, {k: today[k] for k in shared})
    return reasons


def registry_staleness(runs: Mapping[str, RegistryRun]) -> dict[str, list[str]]:
    """:func:`run_staleness` of every run of ``runs``, by name."""
    return {name: run_staleness(run) for name, run in runs.items()}


def stale_summary(reasons: list[str], most: int = 4) -> str:
    """``reasons`` on one line: the first ``most``, then how many more."""
    shown = "; ".join(reasons[:most])
    return shown + (f"; and {len(reasons) - most} more" if len(reasons) > most else "")


def _made_with(run: RegistryRun) -> dict[str, Any]:
    """The config a registry run was made with, every setting it leaves out at its default (a
    setting added since with a default keeps its numbers; a key renamed since is read by its name
    now, so a rename alone departs from nothing). Where today's code no longer reads the file
    whole, the sections it still reads so, the others as written."""
    data = with_current_names(RunConfig, read_run_data(run.path("config.yaml")))
    known = {f.name for f in dataclasses.fields(RunConfig)}
    where = f"{run.name}'s config.yaml"
    try:
        built = _as_data(build(RunConfig, {k: v for k, v in data.items() if k in known}, where=where))
    except UserError:
        return dict(data)
    kept = {k: v for k, v in built.items() if k in data or not isinstance(v, Mapping)}
    return {**kept, **{k: v for k, v in data.items() if k not in known}}


def _as_data(config: RunConfig) -> dict[str, Any]:
    """A config as its ``config.yaml`` holds it (read back with libyaml's parser where PyYAML has it:
    the same safe constructor and resolver, several times faster on a paper preset's seed lists)."""
    return yaml.load(dump_yaml(config), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def _settings(data: Mapping[str, Any]) -> dict[str, Any]:
    return {key: value for key, value in data.items() if key not in IGNORED_KEYS}


def _laned(data: Any) -> bool:
    """Whether any stage of a config's data rolls out more than one lane at a time."""
    if isinstance(data, Mapping):
        return any(
            (key == "lanes" and isinstance(value, int) and value > 1) or _laned(value) for key, value in data.items()
        )
    return False


def registry_status(runs: Mapping[str, RegistryRun]) -> list[dict[str, Any]]:
    """Every canonical run, in the docs' order: its name, ``current``, ``stale`` or ``missing``
    (not in the registry), why it is stale, the wall time it last took
    (:meth:`~metadagger.results.registry.RegistryRun.wall_time`; None when missing) and the command
    that makes it."""
    rows = []
    for canonical in CANONICAL_RUNS:
        found = runs.get(canonical.name)
        reasons = run_staleness(found) if found is not None else []
        rows.append(
            {
                "name": canonical.name,
                "state": "missing" if found is None else "stale" if reasons else "current",
                "reasons": reasons,
                "wall": found.wall_time() if found is not None else None,
                "command": canonical.command,
            }
        )
    return rows
