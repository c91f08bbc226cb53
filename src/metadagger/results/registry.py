"""``results/<run>/``: the small artifacts of each canonical run, and what made them.

A registry run holds the run folder's ``config.yaml``, stage times, summaries (the mapping
diagnostics' among them, where the canonical run asks for them), CSVs, ``report.md`` and its
figures (no pairs, no checkpoints), and a ``manifest.json``: the command, the commit that added it
(after a ``reproduce`` with that commit found nothing left to do), the commits and CPUs that made
each stage, the kernel pins, the wall time, what else ran on the machine, and the SHA-256 of every
file. :func:`add_run` writes one; :func:`load_registry` reads them all back, checked.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import shutil
from pathlib import Path
from typing import Any, Sequence

from metadagger.errors import UserError
from metadagger.evaluation.report.run import duration, origin_took
from metadagger.imitation.lanes import LANE_NUMERICS
from metadagger.pipeline.run_config import RunConfig, load_run, resolve_config
from metadagger.pipeline.stages import StageOptions, reproduce
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import describe_changes
from metadagger.utils.io import read_json, write_json
from metadagger.utils.kernels import machine_description
from metadagger.version import source_revision

#: Where the registry lives, relative to the repository root.
REGISTRY = Path("results")

#: Where a run took pi* from the machine's cache: the record of where it was made.
ORIGIN = "pistar/origin.json"
#: The files of a run folder a registry run keeps (globs relative to the run folder).
KEPT_FILES = (
    "config.yaml",
    "stage_times.json",
    "pistar/metrics.json",
    ORIGIN,  # only where pi* was taken from the machine's cache
    "pairs/summary.json",
    "mappers/*/curves.csv",
    "eval/*.csv",
    "benchmark/queries.csv",
    "benchmark/summary.json",
    "benchmark/labels.jsonl",
    "benchmark/priors.json",
    "benchmark/confirm/queries.csv",
    "benchmark/confirm/summary.json",
    "diagnostics/mapping.json",
    "report/report.md",
    "report/figures/*.png",
    "videos/*.gif",
)
#: Kept files a registry run holds gzipped, as ``NAME.gz`` (the query ledger of a CarRacing paper
#: run is tens of MB of gate scores; gzipped, a third or less).
GZIPPED_FILES = ("benchmark/labels.jsonl",)


@dataclasses.dataclass(frozen=True)
class CanonicalRun:
    """A run the registry holds: its name, the task, the preset, ``--set`` overrides and whether
    it also runs the mapping diagnostics (``--diagnose``: the docs read their section)."""

    name: str
    task: str
    preset: str
    overrides: tuple[str, ...] = ()
    shows: str = ""
    diagnose: bool = False

    @property
    def command(self) -> str:
        """The command that makes it, from the repository root."""
        sets = "".join(f" --set {item}" for item in self.overrides)
        flags = " --diagnose" if self.diagnose else ""
        return f"metadagger reproduce --task {self.task} --preset {self.preset} --out runs/{self.name}{sets}{flags}"


#: The canonical runs, in the order the docs list them.
CANONICAL_RUNS = (
    CanonicalRun("carracing-quick", "carracing", "quick", shows="every stage on CarRacing, small: the Quick start"),
    CanonicalRun("fetch-quick", "fetch", "quick", shows="every stage on FetchPickAndPlace, small"),
    CanonicalRun("carracing-family-quick", "carracing-family", "quick", shows="a CarRacing task family, small"),
    CanonicalRun("fetch-family-quick", "fetch-family", "quick", shows="a Fetch task family, small"),
    CanonicalRun(
        "carracing-echo-quick",
        "carracing-echo",
        "quick",
        shows="CarRacing with hidden steering faults (labels matter), small",
    ),
    CanonicalRun("carracing-paper", "carracing", "paper", shows="the paper's CarRacing setup"),
    CanonicalRun("fetch-paper", "fetch", "paper", shows="the paper's FetchPickAndPlace setup"),
    CanonicalRun(
        "carracing-family-paper",
        "carracing-family",
        "paper",
        diagnose=True,
        shows="the CarRacing family, every head from one shared initialisation",
    ),
    CanonicalRun("fetch-family-paper", "fetch-family", "paper", shows="the Fetch family at paper scale"),
    CanonicalRun(
        "carracing-echo-paper",
        "carracing-echo",
        "paper",
        shows="CarRacing with hidden steering faults (labels matter), judged on two seed sets",
    ),
    CanonicalRun(
        "carracing-family-paper-per-seed-init",
        "carracing-family",
        "paper",
        ("pairs.bc.head_init=seed",),
        shows="the CarRacing family, each seed's own head initialisation",
        diagnose=True,
    ),
)


def canonical_run(name: str) -> CanonicalRun:
    """The canonical run called ``name``; a :class:`UserError` naming the known ones otherwise."""
    for run in CANONICAL_RUNS:
        if run.name == name:
            return run
    raise UserError(
        f"--name {name!r} is not a canonical run; expected one of {', '.join(r.name for r in CANONICAL_RUNS)}"
    )


def add_run(run: str | Path, name: str, *, beside: str, registry: str | Path = REGISTRY, progress: bool = True) -> Path:
    """Put run folder ``run`` into the registry as canonical run ``name``: first ``reproduce`` on
    it with this code (it resumes; on a finished, current run it finds nothing to do; with the
    mapping diagnostics where the canonical run asks for them), then its
    kept files and a manifest into ``registry/name`` (replaced whole). ``beside``: what else ran
    on the machine while the run was made. Returns the registry run's folder.

    Raises:
        UserError: an unknown ``name``; ``run`` is not a run folder of that task, preset and
            overrides, or its config departs from what the canonical command makes now (a
            changed preset); an empty ``beside``.
    """
    canonical = canonical_run(name)
    if not beside.strip():
        raise UserError(
            '--beside is empty; say what else ran on the machine while the run was made ("nothing" if nothing)'
        )
    config = load_run(run, canonical.overrides)
    if (config.task, config.preset) != (canonical.task, canonical.preset):
        raise UserError(
            f"{run} is a run of task {config.task!r}, preset {config.preset!r}; {name} is task "
            f"{canonical.task!r}, preset {canonical.preset!r}: pass the run folder made by `{canonical.command}`"
        )
    departures = config_departures(
        config, resolve_config(canonical.task, canonical.preset, overrides=canonical.overrides)
    )
    if departures:
        raise UserError(
            f"{run}'s config.yaml departs from what `{canonical.command}` makes ({'; '.join(departures[:4])}"
            f"{'; ...' if len(departures) > 4 else ''}): the preset changed since the run was made, or the run "
            "had other --set values; run that command again with the --set that brings each back"
        )
    reproduce(
        canonical.task,
        canonical.preset,
        run,
        overrides=canonical.overrides,
        diagnose=canonical.diagnose,
        options=StageOptions(progress=progress),
    )
    target = Path(registry) / name
    staging = target.with_name(f".{name}.tmp")
    shutil.rmtree(staging, ignore_errors=True)
    files = _copy_kept(Path(run), staging)
    write_json(staging / "manifest.json", _manifest(canonical, Path(run), files, beside))
    shutil.rmtree(target, ignore_errors=True)
    staging.rename(target)
    return target


def config_departures(config: RunConfig, canonical: RunConfig) -> list[str]:
    """``key: run's -> canonical`` for every setting where a run's config departs from its
    canonical command's (the package version and the ``log`` key aside: neither changes a number)."""

    def settings(c: RunConfig) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(c).items() if k not in ("metadagger_version", "log")}

    return describe_changes(settings(config), settings(canonical))


def _copy_kept(run: Path, target: Path) -> dict[str, str]:
    """Copy the kept files of ``run`` into ``target`` (those of :data:`GZIPPED_FILES` gzipped, with no
    time stamp inside); their SHA-256 by relative path."""
    files: dict[str, str] = {}
    for pattern in KEPT_FILES:
        for source in sorted(run.glob(pattern)):
            relative = source.relative_to(run).as_posix()
            data = source.read_bytes()
            if relative in GZIPPED_FILES:
                relative, data = f"{relative}.gz", gzip.compress(data, compresslevel=9, mtime=0)
            (target / relative).parent.mkdir(parents=True, exist_ok=True)
            (target / relative).write_bytes(data)
            files[relative] = hashlib.sha256(data).hexdigest()
    return files


def _manifest(canonical: CanonicalRun, run: Path, files: dict[str, str], beside: str) -> dict[str, Any]:
    stages = read_json(RunLayout(run).stage_times, "the stage times")
    return {
        "name": canonical.name,
        "task": canonical.task,
        "preset": canonical.preset,
        "overrides": list(canonical.overrides),
        "command": canonical.command,
        "commit": source_revision() or "unknown",
        "stages": stages,
        "wall_seconds": round(sum(float(s.get("total_seconds", s.get("seconds", 0.0))) for s in stages.values()), 1),
        "machine": machine_description(),
        "lane_numerics": LANE_NUMERICS,
        "beside": beside.strip(),
        "files": files,
    }


@dataclasses.dataclass(frozen=True)
class RegistryRun:
    """A run of the registry as read back: its folder and manifest."""

    root: Path
    manifest: dict[str, Any]

    @property
    def name(self) -> str:
        return self.root.name

    def path(self, relative: str) -> Path:
        """A kept file of the run."""
        return self.root / relative

    def json(self, relative: str) -> Any:
        """A kept JSON file of the run, read."""
        return read_json(self.path(relative), f"{relative} of registry run {self.name}")

    def wall_time(self) -> str:
        """The run's wall time, all stages and calls; where its pi* was taken from the machine's cache
        (``pistar/origin.json``), what it cost where it was made is said beside it."""
        wall = duration(self.manifest["wall_seconds"])
        if not self.path(ORIGIN).is_file():
            return wall
        origin = self.json(ORIGIN)
        return f"{wall} (pi* taken from the cache, made{origin_took(origin)} by run {Path(origin['run']).name})"


def load_registry(registry: str | Path = REGISTRY, names: Sequence[str] | None = None) -> dict[str, RegistryRun]:
    """The registry's runs by name (those of ``names``, default all canonical ones that are there),
    each checked: a manifest that reads, and every file it lists with its SHA-256.

    Raises:
        UserError: a manifest that does not read, or a file missing or changed since it was added.
    """
    runs: dict[str, RegistryRun] = {}
    for name in names if names is not None else [r.name for r in CANONICAL_RUNS]:
        root = Path(registry) / name
        if not (root / "manifest.json").is_file():
            continue
        manifest = read_json(root / "manifest.json", f"the manifest of registry run {name}")
        for relative, digest in manifest.get("files", {}).items():
            path = root / relative
            if not path.is_file() or hashlib.sha256(path.read_bytes()).hexdigest() != digest:
                raise UserError(
                    f"{path} is {'missing' if not path.is_file() else 'changed'} since the run was added; "
                    f"run `metadagger results add --out runs/{name} --name {name}` again"
                )
        runs[name] = RegistryRun(root, manifest)
    return runs
