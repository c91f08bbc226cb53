"""Every path of a run folder, in one place.

A run folder holds one MetaL DAgger run: its config and every stage's artifacts. Stages, reports
and the command line ask a :class:`RunLayout` for paths instead of joining folder names, so the
layout is written down once (docs/architecture.md shows it as a tree).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MAPPER_FILE = "mapper.safetensors"
"""A mapper folder's trained mapper (written by :func:`metadagger.mapping.train.train_mapper`)."""
CURVES_FILE = "curves.csv"
"""A mapper folder's learning curves."""
SESSION_STAMP = "stamp.json"
"""A labelling session's stamp (:class:`LabelSessionLayout`)."""


@dataclass(frozen=True)
class RunLayout:
    """The paths of the run folder ``root``."""

    root: Path

    def __init__(self, root: str | Path) -> None:
        object.__setattr__(self, "root", Path(root))

    @property
    def config(self) -> Path:
        """The resolved run config (written first, read by every stage)."""
        return self.root / "config.yaml"

    @property
    def stage_times(self) -> Path:
        """Wall time of each stage: its last call's and the sum over all its calls (JSON)."""
        return self.root / "stage_times.json"

    # pi*
    @property
    def pistar_dir(self) -> Path:
        """pi*'s folder."""
        return self.root / "pistar"

    @property
    def pistar(self) -> Path:
        """pi* itself."""
        return self.pistar_dir / "policy.safetensors"

    @property
    def pistar_metrics(self) -> Path:
        """pi*'s success on its own and on unseen seeds, and its expert queries."""
        return self.pistar_dir / "metrics.json"

    @property
    def pistar_stamp(self) -> Path:
        """What pi* is made from (written before its training starts)."""
        return self.pistar_dir / "stamp.json"

    @property
    def pistar_rounds(self) -> Path:
        """Checkpoints of pi*'s fits (resume)."""
        return self.pistar_dir / "rounds"

    @property
    def pistar_origin(self) -> Path:
        """Where pi* was made, when it was taken from the machine's cache (absent when made here)."""
        return self.pistar_dir / "origin.json"

    # pairs
    @property
    def pairs_dir(self) -> Path:
        """The pair store (one tensor file per seed, ``pairs.jsonl``)."""
        return self.root / "pairs"

    @property
    def pairs_summary(self) -> Path:
        """Outcome counts of the pairs."""
        return self.pairs_dir / "summary.json"

    # mappers
    def mapper_dir(self, kind: str) -> Path:
        """The folder of mapper ``kind``."""
        return self.root / "mappers" / kind

    def mapper(self, kind: str) -> Path:
        """The trained mapper of ``kind``."""
        return self.mapper_dir(kind) / MAPPER_FILE

    def mapper_curves(self, kind: str) -> Path:
        """Learning curves of mapper ``kind`` (CSV)."""
        return self.mapper_dir(kind) / CURVES_FILE

    def mapper_curves_figure(self, kind: str) -> Path:
        """Learning curves of mapper ``kind`` (paper Fig. 8)."""
        return self.mapper_dir(kind) / "curves.png"

    # mapper hyperparameter search
    @property
    def tune_dir(self) -> Path:
        """The Optuna studies of ``metadagger tune``."""
        return self.root / "tune"

    def tune_study(self, kind: str) -> Path:
        """The study of mapper ``kind`` (SQLite; a killed study resumes from it)."""
        return self.tune_dir / f"{kind}.db"

    def tune_summary(self, kind: str) -> Path:
        """The best trial of ``kind``'s study, its ``mappers.<kind>`` settings and what the study
        was made from (YAML)."""
        return self.tune_dir / f"{kind}.yaml"

    # evaluation
    @property
    def eval_dir(self) -> Path:
        """Evaluation on unseen seeds."""
        return self.root / "eval"

    def eval_log(self, protocol: str) -> Path:
        """The resume log of a protocol (``mdm`` or ``mdi``): one line per finished seed."""
        return self.eval_dir / ("rows.jsonl" if protocol == "mdm" else f"{protocol}_rows.jsonl")

    def eval_table(self, name: str) -> Path:
        """A table of evaluation rows: ``mdm``, ``oneshot`` or ``mdi``."""
        return self.eval_dir / f"{name}.csv"

    def heads(self, method: str) -> Path:
        """The folder of the heads one method was evaluated with (``<seed>.safetensors``)."""
        return self.eval_dir / "heads" / method

    # benchmark
    @property
    def benchmark_dir(self) -> Path:
        """Success against expert queries."""
        return self.root / "benchmark"

    def confirmation(self) -> RunLayout:
        """The same run with the benchmark's files in ``benchmark/confirm/``: its second set of seeds."""
        return ConfirmationLayout(self.root)

    @property
    def benchmark_log(self) -> Path:
        """The benchmark's resume log."""
        return self.benchmark_dir / "rows.jsonl"

    @property
    def benchmark_table(self) -> Path:
        """One row per (method, setting, seed)."""
        return self.benchmark_dir / "queries.csv"

    @property
    def benchmark_labels(self) -> Path:
        """The query ledger: one line per benchmark row and round, the states it labelled."""
        return self.benchmark_dir / "labels.jsonl"

    @property
    def benchmark_summary(self) -> Path:
        """Per (method, setting): success with its interval, mean reward and queries."""
        return self.benchmark_dir / "summary.json"

    @property
    def benchmark_priors(self) -> Path:
        """The ``prior`` method's strengths and each strength's distance on the validation pairs."""
        return self.benchmark_dir / "priors.json"

    @property
    def benchmark_figure(self) -> Path:
        """Success against mean expert queries."""
        return self.benchmark_dir / "queries.png"

    @property
    def benchmark_coverage_figure(self) -> Path:
        """Each seed's coverage gap against a MetaL DAgger method's gain over its constant twin."""
        return self.benchmark_dir / "coverage.png"

    # mapping diagnostics
    @property
    def diagnostics_dir(self) -> Path:
        """Does a mapper learn anything? (``metadagger diagnose``)."""
        return self.root / "diagnostics"

    @property
    def diagnostics_log(self) -> Path:
        """The resume log of the per-seed diagnostics jobs (state samples, refits)."""
        return self.diagnostics_dir / "seeds.jsonl"

    def diagnostics_seed(self, what: str, seed: int) -> Path:
        """One seed's tensors: ``states`` (its DAgger states' trunk features) or ``noise`` (its
        w_DA from other fit seeds)."""
        return self.diagnostics_dir / what / f"{seed}.safetensors"

    def diagnostics_scaling(self, kind: str, fraction: float) -> Path:
        """The mapper folder of ``kind`` trained on a share of the training pairs."""
        return self.diagnostics_dir / "scaling" / kind / f"{fraction:g}"

    @property
    def diagnostics_summary(self) -> Path:
        """Every diagnostic number of every kind and control."""
        return self.diagnostics_dir / "mapping.json"

    @property
    def diagnostics_figure(self) -> Path:
        """The data-scaling curve."""
        return self.diagnostics_dir / "scaling.png"

    # report
    @property
    def report_dir(self) -> Path:
        """The report and its figures."""
        return self.root / "report"

    @property
    def report(self) -> Path:
        """The Markdown report."""
        return self.report_dir / "report.md"

    @property
    def figures(self) -> Path:
        """The report's figures."""
        return self.report_dir / "figures"

    # TensorBoard
    @property
    def tb_dir(self) -> Path:
        """TensorBoard event files (``log: tensorboard``); view with ``tensorboard --logdir RUN/tb``."""
        return self.root / "tb"

    def tb_run(self, namespace: str) -> Path:
        """The event files of one namespace, e.g. ``pistar`` or ``mapper/dm``."""
        return self.tb_dir / namespace

    # demo
    @property
    def demo_dir(self) -> Path:
        """``metadagger demo``'s output."""
        return self.root / "demo"

    # a person as the expert
    @property
    def label_dir(self) -> Path:
        """``metadagger label``'s sessions, one folder each."""
        return self.root / "label"

    def label_session(self, expert: str, method: str, setting: str, seed: int) -> LabelSessionLayout:
        """The session of gated method ``method`` at ``setting`` on ``seed``, answered by ``expert``
        (``person`` or ``scripted``)."""
        return LabelSessionLayout(self.label_dir / expert / f"{method}@{setting}" / str(seed))

    def label_sessions(self) -> list[LabelSessionLayout]:
        """Every session begun in the run folder (one that holds a stamp), in path order."""
        return [LabelSessionLayout(p.parent) for p in sorted(self.label_dir.glob(f"*/*/*/{SESSION_STAMP}"))]


@dataclass(frozen=True)
class LabelSessionLayout:
    """The files of one labelling session (``RUN/label/<expert>/<method>@<setting>/<seed>/``)."""

    root: Path

    @property
    def stamp(self) -> Path:
        """What the session is made from (written when it begins; a resume must match it)."""
        return self.root / SESSION_STAMP

    @property
    def labels(self) -> Path:
        """Every label given, one line each, appended as it arrives."""
        return self.root / "labels.jsonl"

    @property
    def rows(self) -> Path:
        """One benchmark row per finished round (the row the benchmark makes after that round)."""
        return self.root / "rows.jsonl"

    def head(self, round: int) -> Path:
        """The head after round ``round``'s refit."""
        return self.root / "heads" / f"{round}.safetensors"


class ConfirmationLayout(RunLayout):
    """A run folder whose benchmark files are those of its confirmation seeds (``benchmark/confirm/``)."""

    @property
    def benchmark_dir(self) -> Path:
        return self.root / "benchmark" / "confirm"

    def confirmation(self) -> RunLayout:
        return self
