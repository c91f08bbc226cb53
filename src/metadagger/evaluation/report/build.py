"""``report/report.md`` and its figures, built only from a run's CSV/JSON artifacts.

Sections appear for the stages a run has finished, one module each: the run itself (stage wall
times, pi*, pairs and their split, mappers: :mod:`~metadagger.evaluation.report.run`), MDM (Tables 1-2, Fig. 4:
:mod:`~metadagger.evaluation.report.mdm`), one-shot (Tables 3-5:
:mod:`~metadagger.evaluation.report.oneshot`), MDI (Table 7, Fig. 5:
:mod:`~metadagger.evaluation.report.mdi`) and success against expert queries
(:mod:`~metadagger.evaluation.report.benchmark`); the sessions a person labelled
(:mod:`~metadagger.evaluation.report.label`); for a task family, each unseen seed's variation beside
every method's outcome (:mod:`~metadagger.evaluation.report.family`). A figure that cannot be
drawn is a warning on stderr and one line in its place: it never costs the report.
"""

from __future__ import annotations

from pathlib import Path

from metadagger.errors import UserError
from metadagger.evaluation.report.benchmark import benchmark_section
from metadagger.evaluation.report.diagnostics import diagnostics_section
from metadagger.evaluation.report.family import family_section
from metadagger.evaluation.report.label import label_section
from metadagger.evaluation.report.mdi import mdi_section
from metadagger.evaluation.report.mdm import mdm_section
from metadagger.evaluation.report.oneshot import oneshot_section
from metadagger.evaluation.report.run import mappers_section, pairs_section, pistar_section, run_section
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.made_by import VERSION_KEY, check_version
from metadagger.utils.io import check_writable, write_text
from metadagger.utils.yaml_config import read_run_data

SECTIONS = (
    run_section,
    pistar_section,
    pairs_section,
    mappers_section,
    diagnostics_section,
    mdm_section,
    oneshot_section,
    mdi_section,
    benchmark_section,
    label_section,
    family_section,
)


def build_report(layout: RunLayout) -> Path:
    """Write the report (+ figures) from the run's artifacts; return its path.

    Raises:
        UserError: the folder holds no run (no config), its config records another metadagger
            version, or no stage has written anything yet.
    """
    if not layout.config.is_file():
        raise UserError(
            f"nothing has been run in {layout.root} (no config.yaml there); "
            "pass the --out of a run started with `metadagger pistar` or `metadagger reproduce`"
        )
    config = read_run_data(layout.config)
    if VERSION_KEY in config:  # a folder of another version holds artifacts this code reads otherwise
        check_version(layout.config, config)
    check_writable(layout.report_dir)  # before any figure is drawn
    parts = [line for section in SECTIONS for line in section(layout)]
    if not parts:
        raise UserError(
            f"nothing to report in {layout.root}: no stage has finished yet; run `metadagger reproduce` or a stage "
            "first"
        )
    return write_text(layout.report, "\n".join([_title(layout), "", *parts]) + "\n")


def _title(layout: RunLayout) -> str:
    config = read_run_data(layout.config)
    return (
        f"# MetaL DAgger report: {config.get('task', '?')}, preset {config.get('preset', '?')} (`{layout.root.name}`)"
    )
