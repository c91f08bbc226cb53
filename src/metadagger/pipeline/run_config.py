"""A run folder's configuration: written first (``<run>/config.yaml``), read by every later stage.

``metadagger pistar --task T --preset P --out RUN`` creates it from a preset; ``metadagger
pairs --out RUN`` and the later stages read it back, so a run is described by its folder alone.
The stage commands also take ``--set section.key=value`` overrides (the value read as YAML), validated
by the same builder as the presets; the config a stage runs with is written back to the folder
(:func:`~metadagger.pipeline.stage_runs.records_config`), and put back as it was when the stage refuses.

``config.yaml`` records the metadagger version that created the folder (``metadagger_version``, in
no stamp); a folder made by another major.minor version, or before versions were recorded (0.2),
is refused with one line (:func:`~metadagger.runfolder.made_by.check_version`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Sequence

import yaml

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.diagnose import DiagnoseConfig
from metadagger.evaluation.mdi import MDIConfig
from metadagger.evaluation.mdm import EvalConfig
from metadagger.evaluation.tensorboard import require_tensorboard
from metadagger.mapping.config import MapperConfig, paper_config
from metadagger.mapping.registry import kind_names, learned_names
from metadagger.metal_dagger.pairs import PairConfig
from metadagger.metal_dagger.pistar import PiStarConfig
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import run_lock
from metadagger.runfolder.made_by import VERSION_KEY, check_version
from metadagger.tasks import check_task
from metadagger.utils.device import resolve_device
from metadagger.utils.io import write_text
from metadagger.utils.kernels import pin_cpu_kernels
from metadagger.utils.yaml_config import (
    STAMPED_UNLESS_DEFAULT,
    build,
    dump_yaml,
    read_run_data,
    read_yaml_mapping,
    to_dict,
    with_current_names,
)
from metadagger.version import __version__

LOGS = ("none", "tensorboard")
"""Values of :attr:`RunConfig.log`."""
PRESETS = ("quick", "paper", "ci")
"""The packaged presets of every built-in task (``presets/<task>.yaml``)."""
CHOSEN_AT_START = ("task", "preset", "device")
"""Config keys a run takes from ``--task``/``--preset``/``--device`` when it starts, never from ``--set``."""


@dataclass(frozen=True)
class RunConfig:
    """Every stage of one MetaL DAgger run."""

    RENAMED: ClassVar[dict[str, str]] = {"groundtruth": "pistar"}
    """Sections of an older version's presets, by their names now (an error names the new one)."""

    metadagger_version: str = __version__
    """The metadagger version that made the run folder (kept as the folder's stages rewrite its
    config; in no stamp, so it changes no other artifact)."""
    task: str = "carracing"
    """Task name (``metadagger.make_task``)."""
    preset: str = "quick"
    """The preset this config came from (informational)."""
    max_episode_steps: int = 1000
    """Step limit of every episode of every stage."""
    task_options: dict | None = field(default=None, metadata=STAMPED_UNLESS_DEFAULT)
    """The task's own keyword arguments beyond its episode length, e.g. ``{echo_rows: 6}`` for
    ``carracing-echo`` (a variant of a task); None: its defaults."""
    pistar: PiStarConfig = field(default_factory=PiStarConfig)
    """pi*: multi-seed BC + DAgger."""
    pairs: PairConfig = field(default_factory=PairConfig)
    """Per-seed (w_BC, w_DA) pairs."""
    split_seed: int = 0
    """Seed of the train/validation split of the kept pairs."""
    mappers: dict = field(default_factory=dict)
    """Per-kind overrides of the paper's mapper settings, e.g. ``{sam: {epochs: 300}}`` (keys: learned kinds)."""
    evaluate: EvalConfig = field(default_factory=EvalConfig)
    """MDM and one-shot evaluation on unseen seeds."""
    mdi: MDIConfig | None = None
    """The MDI protocol (paper Table 6) on unseen seeds; None: not run (CarRacing). Its ``bc``
    defaults to ``pairs.bc`` (:attr:`mdi_config`)."""
    benchmark: BenchmarkConfig | None = None
    """Success against expert queries (DAgger, gated DAgger, MetaL DAgger) on unseen seeds; None: not run."""
    diagnose: DiagnoseConfig = field(default_factory=DiagnoseConfig)
    """The mapping diagnostics (``metadagger diagnose``): state samples, noise ceiling, scaling shares."""
    device: str = "cpu"
    """Where the run computes: ``cpu``, or ``cuda`` (a GPU: the lanes' trunk forwards, the batched
    head fits, pi*'s whole-network fits; utils/device.py). Chosen with ``--device`` when the run
    starts and kept: a run folder never mixes CPU and GPU artifacts."""
    log: str = "none"
    """``tensorboard``: each stage also writes its training curves and evaluations as TensorBoard
    scalars under ``RUN/tb/``, from its artifacts (docs/tensorboard.md; the ``tensorboard`` extra); ``none``: off."""

    def __post_init__(self) -> None:
        check_log(self.log)
        if self.device not in ("cpu", "cuda"):
            raise UserError(f"device must be cpu or cuda, got {self.device!r}; a run's device is chosen with --device")
        if self.log == "tensorboard":
            require_tensorboard()  # a missing extra fails now, not after the first stage
        if self.max_episode_steps < 1:
            raise UserError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")
        if self.task_options is not None and (
            not isinstance(self.task_options, dict) or "max_episode_steps" in self.task_options
        ):
            raise UserError(
                f"task_options must be a mapping of the task's keyword arguments (its episode length is "
                f"max_episode_steps), got {self.task_options!r}; e.g. --set 'task_options={{echo_rows: 6}}'"
            )
        gt = self.pistar.used_seeds
        shared = sorted(gt & set(self.pairs.seeds))
        if shared:
            raise UserError(f"pairs.seeds overlap pi*'s seeds ({shared[:5]}...); pick disjoint ranges")
        seen = sorted(self.seen_seeds & self.unseen_seeds)
        if seen:
            raise UserError(
                f"evaluate.seeds, mdi.seeds and benchmark's seeds must be unseen, but {seen[:5]} are pi*'s or pairs' "
                "seeds; pick disjoint ranges"
            )
        unknown = sorted(set(self.mappers) - set(learned_names()))
        if unknown:
            raise UserError(f"mappers has unknown kind(s) {unknown}; expected one of {', '.join(learned_names())}")
        if self.benchmark is not None and "mdi" in self.benchmark.methods and self.mdi is None:
            raise UserError("benchmark.methods has mdi, but the run has no mdi section; drop mdi or add an mdi section")
        if self.mdi is not None and self.mdi.bc is not None and self.mdi.bc != self.pairs.bc:
            raise UserError(
                "mdi.bc differs from pairs.bc, but DAgger-MDI must fit w_BC exactly as the pairs did (the mapper "
                "learned from those); drop mdi.bc (it defaults to pairs.bc)"
            )
        for kind in self.mappers:
            self.mapper_config(kind)  # validates the overrides now, not hours later

    @property
    def seen_seeds(self) -> set[int]:
        """Every seed pi* or the pairs learn from (pi*'s own check seeds included)."""
        return self.pistar.used_seeds | set(self.pairs.seeds)

    @property
    def unseen_seeds(self) -> set[int]:
        """Every seed the run measures on and learns from nowhere: evaluation, MDI, benchmark and
        confirmation seeds."""
        return (
            set(self.evaluate.seeds)
            | (set(self.mdi.seeds) if self.mdi else set())
            | (set(self.benchmark.seeds) | set(self.benchmark.confirm_seeds) if self.benchmark else set())
        )

    @property
    def spare_seed(self) -> int:
        """The first seed above every seed the run names: one no stage rolls out, for timing a
        setting (a lane width) without rolling out an evaluation seed."""
        return max(self.seen_seeds | self.unseen_seeds) + 1

    def mapper_config(self, kind: str) -> MapperConfig:
        """The paper's settings for mapper ``kind`` with this run's overrides applied."""
        paper = dataclasses.asdict(paper_config(kind))
        return build(MapperConfig, {**paper, **(self.mappers.get(kind) or {})}, where=f"mappers.{kind}")

    @property
    def mdi_config(self) -> MDIConfig | None:
        """The MDI section with ``bc`` resolved to ``pairs.bc``; None when the run has none."""
        return None if self.mdi is None else dataclasses.replace(self.mdi, bc=self.pairs.bc)

    @property
    def mapper_kinds(self) -> tuple[str, ...]:
        """The mapper kinds this run uses (``evaluate.methods``, ``mdi.mapper`` and
        ``mdi.controls``), in registry order (:mod:`metadagger.mapping.registry`)."""
        used = set(self.evaluate.methods) | (set(self.mdi.kinds.values()) if self.mdi else set())
        if self.benchmark is not None and "mdi" in self.benchmark.methods and self.mdi is not None:
            used.add(self.mdi.mapper)
        return tuple(kind for kind in kind_names() if kind in used)

    @property
    def task_kwargs(self) -> dict:
        """Keyword arguments of ``make_task`` for this run."""
        return {"max_episode_steps": self.max_episode_steps, **(self.task_options or {})}


@functools.lru_cache(maxsize=None)
def _packaged_presets(task: str) -> Any:
    """The ``presets`` of ``task``'s packaged YAML file, read once (callers get a copy)."""
    try:
        text = resources.files("metadagger.pipeline.presets").joinpath(f"{task}.yaml").read_text()
    except FileNotFoundError:
        raise UserError(
            f"task {task!r} has no packaged presets: pass --presets FILE (see docs/custom_task.md)"
        ) from None
    return yaml.safe_load(text).get("presets")


def load_preset(task: str, preset: str, presets_file: str | Path | None = None) -> dict[str, Any]:
    """The raw mapping of one preset: from the task's packaged YAML file, or from ``presets_file``
    (a YAML file of the same layout, ``presets: {name: {section: ...}}``, any preset names)."""
    check_task(task)
    if presets_file is None:
        if preset not in PRESETS:
            raise UserError(
                f"unknown preset {preset!r}: expected one of {', '.join(PRESETS)}, "
                "or pass --presets FILE with presets of your own (see docs/custom_task.md)"
            )
        where = f"metadagger/pipeline/presets/{task}.yaml"
        presets = copy.deepcopy(_packaged_presets(task))
    else:
        where = str(presets_file)
        presets = read_yaml_mapping(
            presets_file, "presets file", "fix it or pass another (layout: docs/custom_task.md)"
        ).get("presets")
    if not isinstance(presets, dict) or not presets:
        raise UserError(
            f"{where} has no presets: expected a top-level 'presets:' mapping of preset names to stage sections "
            "(see docs/custom_task.md)"
        )
    if preset not in presets:
        raise UserError(
            f"{where} has no preset {preset!r}: expected one of {', '.join(map(str, presets))}; pass one with --preset"
        )
    if not isinstance(presets[preset], dict):
        raise UserError(
            f"{where}: preset {preset!r} is {presets[preset]!r}, not a mapping of stage sections; "
            f"give it sections, e.g. {preset}: {{pairs: {{dagger_rounds: 4}}}}"
        )
    return presets[preset]


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """``data`` with each ``section.key=value`` of ``overrides`` set (the value read as YAML, so
    ``evaluate.methods=[dm, sam]`` gives a list); returns a new mapping."""
    data = to_dict(data)
    for item in overrides:
        path, sep, text = item.partition("=")
        keys = path.strip().split(".")
        if not sep or not all(keys):
            raise UserError(f"bad --set {item!r}: expected section.key=value, e.g. --set pairs.dagger_rounds=4")
        if keys[0] == VERSION_KEY:
            raise UserError(
                f"bad --set {item!r}: {VERSION_KEY} records the metadagger version that made the run folder; "
                "it cannot be set"
            )
        if keys[0] in CHOSEN_AT_START:
            raise UserError(
                f"bad --set {item!r}: the {keys[0]} is chosen with --{keys[0]}, not --set, and a run keeps the one it "
                f"started with; pass --{keys[0]} instead (with a new --out for a started run)"
            )
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise UserError(
                f"bad --set {item!r}: the value is not YAML ({exc.problem}); quote it, e.g. --set "
                "'evaluate.methods=[dm, sam]'"
            ) from None
        node = data
        for key in keys[:-1]:
            child = node.get(key)
            if child is None:
                child = node[key] = {}
            if not isinstance(child, dict):
                raise UserError(f"bad --set {item!r}: {key} is a value ({child!r}), not a section")
            node = child
        node[keys[-1]] = value
    return data


def resolve_config(
    task: str,
    preset: str,
    presets_file: str | Path | None = None,
    overrides: Sequence[str] = (),
    device: str = "cpu",
) -> RunConfig:
    """The config of a new run: a preset (packaged, or from ``presets_file``) with ``overrides``,
    on ``device`` (a ``--device`` value, resolved: :func:`~metadagger.utils.device.resolve_device`)."""
    sections = {k: v for k, v in load_preset(task, preset, presets_file).items() if k != "demo"}
    resolved = resolve_device(device)
    data = apply_overrides({"task": task, "preset": preset, "device": resolved, **sections}, overrides)
    return build(RunConfig, data, where=f"{task}.{preset}" + (" with --set" if overrides else ""))


def init_run(
    run: str | Path,
    task: str,
    preset: str,
    presets_file: str | Path | None = None,
    overrides: Sequence[str] = (),
    device: str | None = None,
) -> RunConfig:
    """Create ``<run>/config.yaml`` from a preset and ``overrides`` on ``device`` (a ``--device``
    value; None: ``cpu``), or read the existing one (of the same task and preset, and the same
    device where one is named) with ``overrides`` applied; an existing run's file is updated by
    the stage that runs with the result (:func:`~metadagger.pipeline.stage_runs.records_config`).
    Pins the CPU kernels first (:func:`~metadagger.utils.kernels.pin_cpu_kernels`), as the command
    line does."""
    pin_cpu_kernels()
    layout = RunLayout(run)
    if layout.root.exists() and not layout.root.is_dir():
        raise UserError(f"--out {run} is a file, not a run folder; pass a folder path")
    if layout.config.is_file():
        config = load_run(run, overrides)
        if (config.task, config.preset) != (task, preset):
            raise UserError(
                f"run folder {run} holds task {config.task!r} preset {config.preset!r}, not {task!r} {preset!r}; "
                "use another --out or the same task and preset"
            )
        if device not in (None, "auto") and resolve_device(device) != config.device:
            raise UserError(
                f"run folder {run} was made on {config.device}, not {device}: a run folder never mixes CPU and GPU "
                f"artifacts; use another --out, or --device {config.device} (or none) to resume it"
            )
        return config
    config = resolve_config(task, preset, presets_file, overrides, device or "cpu")
    with run_lock(run):
        save_run(run, config)
    return config


def check_log(value: str, name: str = "log") -> None:
    """Raise a :class:`UserError` unless ``value`` is one of :data:`LOGS` (``name``: the key or option that gave it)."""
    if value not in LOGS:
        raise UserError(f"{name} must be one of {', '.join(LOGS)}, got {value!r}")


def load_run(run: str | Path, overrides: Sequence[str] = ()) -> RunConfig:
    """Read a run's config with ``overrides`` applied (the file is left as it is: the stage that
    runs with the result writes it, :func:`~metadagger.pipeline.stage_runs.records_config`); a
    missing or broken file is a :class:`UserError`. Pins the CPU kernels first
    (:func:`~metadagger.utils.kernels.pin_cpu_kernels`), as the command line does."""
    pin_cpu_kernels()
    path = RunLayout(run).config
    if not path.is_file():
        raise UserError(
            f"no run at {run} (missing {path}); start one with `metadagger pistar --task T --preset P --out {run}`"
        )
    data = read_run_data(path)
    check_version(path, data)
    data = with_current_names(RunConfig, data)  # a folder of this version written before a key's rename
    return build(RunConfig, apply_overrides(data, overrides), where=str(path) + (" with --set" if overrides else ""))


def save_run(run: str | Path, config: RunConfig) -> None:
    """Write ``config`` as the run's ``config.yaml``."""
    write_text(RunLayout(run).config, dump_yaml(config))
