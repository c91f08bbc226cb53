"""A run folder's configuration: written first (``<run>/config.yaml``), read by every later stage.

``metadagger groundtruth --task T --preset P --out RUN`` creates it from a preset; ``metadagger
pairs --out RUN`` and the later stages read it back, so a run is described by its folder alone.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from metadagger.config import build, dump_yaml, load_preset
from metadagger.errors import UserError
from metadagger.io import write_text
from metadagger.evaluation.mdi import MDIConfig
from metadagger.evaluation.mdm import MAPPER_METHODS, EvalConfig
from metadagger.mapping.train import MapperConfig, paper_config
from metadagger.metal.groundtruth import GroundTruthConfig
from metadagger.metal.pairs import PairConfig


@dataclass(frozen=True)
class RunConfig:
    """Every stage of one MetaL DAgger run."""

    task: str = "carracing"
    """Task name (``metadagger.make_task``)."""
    preset: str = "quick"
    """The preset this config came from (informational)."""
    max_episode_steps: int = 1000
    """Step limit of every episode of every stage."""
    groundtruth: GroundTruthConfig = field(default_factory=GroundTruthConfig)
    """pi*: multi-seed BC + DAgger."""
    pairs: PairConfig = field(default_factory=PairConfig)
    """Per-seed (w_BC, w_DA) pairs."""
    split_seed: int = 0
    """Seed of the train/validation split of the kept pairs."""
    mappers: dict = field(default_factory=dict)
    """Per-kind overrides of the paper's mapper settings, e.g. ``{sam: {epochs: 300}}`` (keys dm, sam, tam)."""
    evaluate: EvalConfig = field(default_factory=EvalConfig)
    """MDM and one-shot evaluation on unseen seeds."""
    mdi: MDIConfig | None = None
    """The MDI protocol (paper Table 6) on unseen seeds; None: not run (CarRacing)."""

    def __post_init__(self) -> None:
        if self.max_episode_steps < 1:
            raise UserError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")
        gt = set(self.groundtruth.seeds) | set(self.groundtruth.eval_seeds)
        shared = sorted(gt & set(self.pairs.seeds))
        if shared:
            raise UserError(f"pairs.seeds overlap pi*'s seeds ({shared[:5]}...); pick disjoint ranges")
        unseen = set(self.evaluate.seeds) | (set(self.mdi.seeds) if self.mdi else set())
        seen = sorted((gt | set(self.pairs.seeds)) & unseen)
        if seen:
            raise UserError(f"evaluate.seeds and mdi.seeds must be unseen, but {seen[:5]} are pi*'s or pairs' seeds; pick disjoint ranges")
        unknown = sorted(set(self.mappers) - {"dm", "sam", "tam"})
        if unknown:
            raise UserError(f"mappers has unknown kind(s) {unknown}; expected dm, sam or tam")
        for kind in self.mappers:
            self.mapper_config(kind)  # validates the overrides now, not hours later

    def mapper_config(self, kind: str) -> MapperConfig:
        """The paper's settings for mapper ``kind`` with this run's overrides applied."""
        paper = dataclasses.asdict(paper_config(kind))
        return build(MapperConfig, {**paper, **(self.mappers.get(kind) or {})}, where=f"mappers.{kind}")

    @property
    def mapper_kinds(self) -> tuple[str, ...]:
        """The mapper kinds this run uses (``evaluate.methods``, ``mdi.mapper`` and
        ``mdi.controls``), in :data:`~metadagger.evaluation.mdm.MAPPER_METHODS` order."""
        used = set(self.evaluate.methods) | (set(self.mdi.kinds.values()) if self.mdi else set())
        return tuple(kind for kind in MAPPER_METHODS if kind in used)

    @property
    def task_kwargs(self) -> dict:
        """Keyword arguments of ``make_task`` for this run."""
        return {"max_episode_steps": self.max_episode_steps}


def config_path(run: str | Path) -> Path:
    """Where a run's config lives."""
    return Path(run) / "config.yaml"


def init_run(run: str | Path, task: str, preset: str, presets_file: str | Path | None = None) -> RunConfig:
    """Create ``<run>/config.yaml`` from a preset (packaged, or from ``presets_file``), or read the
    existing one (which must match)."""
    path = config_path(run)
    if path.is_file():
        config = load_run(run)
        if (config.task, config.preset) != (task, preset):
            raise UserError(
                f"run folder {run} holds task {config.task!r} preset {config.preset!r}, not {task!r} {preset!r}; "
                "use another --out or the same task and preset"
            )
        return config
    sections = {k: v for k, v in load_preset(task, preset, presets_file).items() if k != "demo"}
    config = build(RunConfig, {"task": task, "preset": preset, **sections}, where=f"{task}.{preset}")
    write_text(path, dump_yaml(config))
    return config


def load_run(run: str | Path) -> RunConfig:
    """Read a run's config; a missing or broken file is a :class:`UserError`."""
    path = config_path(run)
    if not path.is_file():
        raise UserError(f"no run at {run} (missing {path}); start one with `metadagger groundtruth --task T --preset P --out {run}`")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise UserError(f"{path} is not valid YAML ({exc}); fix or delete it") from None
    return build(RunConfig, data, where=str(path))
