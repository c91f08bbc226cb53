"""The kinds of generated block (:mod:`metadagger.results.blocks`), each a function of the registry.

=========================  ============================================================
block                      writes
=========================  ============================================================
``glance``                 the paper's figures beside the paper-preset runs': the best
                           MetaL DAgger method, the two MDM controls, BC refitted, DAgger
                           and the best gate, each with its interval and queries per seed
``runs``                   every canonical run: command, wall time, CPU, what it shows
``report RUN HEADING``     the section of RUN's ``report.md`` under HEADING (its figures
                           linked where they lie in the registry)
``figure RUNS PATH ALT``   an image of the first of RUNS (comma-separated) that has it
``manifest RUN``           what made RUN: commit, CPU and kernels, wall time, what ran beside
=========================  ============================================================

A block about a run the registry does not hold yet says so, with the command that makes it.
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any, Callable, Mapping

from metadagger.evaluation.benchmark_figure import plot_queries
from metadagger.evaluation.benchmark_summary import BUDGET_SHARES, budget_reading
from metadagger.evaluation.methods import BC_REFIT, MDI_METHODS, MDM_PREFIX, gated_methods, reference_methods
from metadagger.evaluation.report_run import duration
from metadagger.evaluation.rows import read_csv
from metadagger.evaluation.tables import markdown_table, method_label, pct
from metadagger.results.registry import CANONICAL_RUNS, RegistryRun, canonical_run
from metadagger.results.staleness import stale_summary

#: The controls, by benchmark method: zero-query heads every mapper must beat.
CONTROLS = ("mdm-pistar-head", "mdm-mean-da")

#: The paper's own figures for the at-a-glance table (Tables 1 and 7 of the paper), by task; the
#: paper reports neither queries nor task families.
PAPER_FIGURES = {
    "carracing": "SAM 86.7% raw (89.3% adjusted), 20 unseen seeds; DM, TAM 53.3%",
    "fetch": "DAgger-MDI 53% one-shot, 74% two-shot (DAgger-BC 17%, 34%; DAgger 27%, 44%)",
}


@dataclasses.dataclass(frozen=True)
class BlockContext:
    """What a block is rendered with: the registry's runs, the repository root, and the file the
    block stands in (links are written relative to it)."""

    runs: dict[str, RegistryRun]
    root: Path
    file: Path | None = None
    draw: bool = False
    """Whether blocks that draw a figure from the registry's data write it (``results build``, not ``check``)."""
    stale: Mapping[str, list[str]] = dataclasses.field(default_factory=dict)
    """Why each stale run of :attr:`runs` is stale (:func:`~metadagger.results.staleness.run_staleness`);
    a run not named here is current."""

    def at(self, file: Path) -> "BlockContext":
        """This context for a block in ``file``."""
        return dataclasses.replace(self, file=file)

    def link(self, target: Path) -> str:
        """``target`` relative to the block's file, with forward slashes."""
        base = (self.file or self.root / "README.md").resolve().parent
        return Path(os.path.relpath(target.resolve(), base)).as_posix()


def _missing(name: str) -> str:
    run = canonical_run(name)
    return (
        f"*Not in the registry yet: `{run.command}`, then `metadagger results add --out runs/{run.name} "
        f'--name {run.name} --beside "..."`.*'
    )


def _cell(entry: dict[str, Any] | None) -> str:
    """success (interval) @ queries per seed."""
    if entry is None:
        return "-"
    return (
        f"{pct(entry['success_rate'])} ({entry['successes']}/{entry['seeds']}; {pct(entry['success_ci_low'])}-"
        f"{pct(entry['success_ci_high'])}) at {entry['mean_queries']:,.0f}"
    )


def _best(entries: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The highest success, then the fewest queries; None for none."""
    return min(entries, key=lambda e: (-e["success_rate"], e["mean_queries"])) if entries else None


def _labelled(entry: dict[str, Any] | None) -> str:
    if entry is None:
        return "-"
    setting = f" {entry['setting']}" if entry["setting"] else ""
    return f"{method_label(entry['method'])}{setting}: {_cell(entry)}"


def glance(context: BlockContext) -> str:
    """The at-a-glance table of the paper-preset runs, then of the quick ones."""
    header = (
        "run",
        "the paper",
        "best MetaL DAgger",
        "control: pi*-head",
        "control: mean-DA",
        "control: BC refitted",
        "DAgger (last round)",
        "best gate",
        "ceiling: oracle",
    )
    rows = []
    for run in sorted(CANONICAL_RUNS, key=lambda r: r.preset != "paper"):
        found = context.runs.get(run.name)
        if found is None or not found.path("benchmark/summary.json").is_file():
            rows.append(
                (
                    f"`{run.name}`",
                    PAPER_FIGURES.get(run.task, "-") if run.preset == "paper" else "",
                    "not run yet",
                    "",
                    "",
                    "",
                    "",
                    "",
                    "",
                )
            )
            continue
        entries = [
            e for e in found.json("benchmark/summary.json")["entries"] if float(e.get("demo_fraction", 1.0)) == 1.0
        ]
        by_method = {e["method"]: e for e in entries}
        mappers = [
            e
            for e in entries
            if (e["method"].startswith(MDM_PREFIX) and e["method"] not in CONTROLS)
            or e["method"] == MDI_METHODS["dagger-mdi"]
        ]
        dagger = [e for e in entries if e["method"] == "dagger"]
        gates = [e for e in entries if e["method"] in gated_methods()]
        oracle = [e for e in entries if e["method"] in reference_methods()]
        rows.append(
            (
                _run_cell(context, run.name),
                PAPER_FIGURES.get(run.task, "-") if run.preset == "paper" else "",
                _labelled(_best(mappers)),
                _cell(by_method.get(CONTROLS[0])),
                _cell(by_method.get(CONTROLS[1])),
                _cell(by_method.get(BC_REFIT)),
                _cell(max(dagger, key=lambda e: int(e["setting"])) if dagger else None),
                _labelled(_best(gates)),
                _labelled(_best(oracle)),
            )
        )
    note = (
        "Success on the run's unseen seeds (95% Wilson interval) at mean expert queries per seed (the "
        "demonstration's included; the controls use none), every method on the whole demonstration (the shorter "
        "ones of `benchmark.demo_fractions` are in each run's report), one benchmark rollout per seed under the "
        "pairs' early stop (`pairs.early_stop`, set on the Fetch presets: a rollout it cuts counts as a failure, "
        "so an MDM row can stand below the run's Table 1, rolled out without it). BC refitted: w_BC refitted as "
        "DAgger refits it, on the demonstration alone (`bc-refit`; '-' for a run that has no such row). Best "
        "MetaL DAgger: the best MDM mapper or DAgger-MDI. Ceiling: the oracle rule, which labels exactly the states "
        "where the learner is wrong ('-' for a run made before it). A run marked 'stale' was made by a config or "
        "numerics other than what its command makes now; the lines under the table name what departed "
        "(docs/results.md). It and the best gate are chosen on these same seeds, which favours "
        "them; paired comparisons are in each run's report."
    )
    return "\n".join([note, "", *markdown_table(header, rows), *_stale_lines(context)])


def runs_table(context: BlockContext) -> str:
    """Every canonical run: its command, wall time, CPU and what it shows."""
    rows = []
    for run in CANONICAL_RUNS:
        found = context.runs.get(run.name)
        wall = duration(found.manifest["wall_seconds"]) if found else "not run yet"
        cpu = found.manifest["machine"]["cpu"] if found else "-"
        rows.append((f"`{run.name}`", f"`{run.command}`", wall, cpu, _status(context, run.name), run.shows))
    note = (
        "Wall time as measured, on the CPU named, with the other work the run's manifest names running beside it "
        "on the same cores (docs/findings.md gives each run's); on an idle machine a run takes less. Status: "
        "current, or stale with what departed (`setting: run's -> today's`): a stale run's numbers are those of "
        "the config and code that made it, kept and marked until its command is run again and `metadagger results "
        "add` takes the new folder (`metadagger results status` lists them)."
    )
    return "\n".join([note, "", *markdown_table(("run", "command", "wall time", "CPU", "status", "shows"), rows)])


def _status(context: BlockContext, name: str) -> str:
    """ "current", "stale: what departed", or "-" for a run the registry does not hold."""
    if name not in context.runs:
        return "-"
    reasons = context.stale.get(name)
    return f"stale: {stale_summary(reasons)}" if reasons else "current"


def _run_cell(context: BlockContext, name: str) -> str:
    """A run's name for a table's first column, marked where the run is stale."""
    return f"`{name}` (stale)" if context.stale.get(name) else f"`{name}`"


def _stale_lines(context: BlockContext, names: list[str] | None = None) -> list[str]:
    """One line per stale run of ``names`` (default: every run of the registry) naming what departed,
    after a blank line; nothing when all are current."""
    stale = [n for n in (names if names is not None else context.runs) if context.stale.get(n)]
    lines = [f"*Stale `{n}` (run's -> today's): {stale_summary(context.stale[n])}.*" for n in stale]
    return ["", *lines] if lines else []


def report_section(context: BlockContext, name: str, heading: str) -> str:
    """The section of run ``name``'s report under the heading that starts with ``heading`` (its
    body, to the next heading of the same or a higher level), figure links made to point into
    the registry."""
    found = context.runs.get(name)
    if found is None:
        return _missing(name)
    lines = found.path("report/report.md").read_text().splitlines()
    start = next(
        (i for i, line in enumerate(lines) if line.lstrip("#").strip().startswith(heading) and line.startswith("#")),
        None,
    )
    if start is None:
        raise ValueError(f"registry run {name}'s report has no heading {heading!r}")
    level = len(lines[start]) - len(lines[start].lstrip("#"))
    end = next(
        (
            i
            for i in range(start + 1, len(lines))
            if lines[i].startswith("#") and len(lines[i]) - len(lines[i].lstrip("#")) <= level
        ),
        len(lines),
    )
    figures = found.path("report")
    body = [
        re.sub(r"\]\((figures/[^)]+)\)", lambda m: f"]({context.link(figures / m.group(1))})", line)
        for line in lines[start + 1 : end]
    ]
    return "\n".join([*body, *_stale_lines(context, [name])]).strip("\n")


def figure(context: BlockContext, names: str, path: str, alt: str) -> str:
    """An image of the first of the registry runs ``names`` (comma-separated) that has it, with
    the run it shows."""
    for name in names.split(","):
        found = context.runs.get(name)
        if found is not None and found.path(path).is_file():
            return "\n".join(
                [f"![{alt}]({context.link(found.path(path))})\n\n*Run `{name}`.*", *_stale_lines(context, [name])]
            )
    return _missing(names.split(",")[0])


def budgets_table(context: BlockContext) -> str:
    """Every canonical run read at equal budgets, from its ``benchmark/queries.csv``: the best method
    (the oracle and the controls aside) at each budget and by the area under the curve, with its
    paired difference from the best gate there, and the oracle's success beside it."""
    rows = []
    shares: list[float] = []
    for run in sorted(CANONICAL_RUNS, key=lambda r: r.preset != "paper"):
        found = context.runs.get(run.name)
        reading = None
        if found is not None and found.path("benchmark/queries.csv").is_file():
            reading = budget_reading(read_csv(found.path("benchmark/queries.csv")))
        if reading is None:
            rows.append((f"`{run.name}`", "not run yet" if found is None else "no DAgger rows", "", "", ""))
            continue
        shares = [b["share"] for b in reading["budgets"]]
        rows.append(
            (_run_cell(context, run.name), *(_at_budget(b) for b in reading["budgets"]), _by_area(reading)),
        )
    header = ("run", *(f"demonstration + {s:.0%} of DAgger's queries" for s in shares or BUDGET_SHARES), "by area")
    note = (
        "Every method read at the same spend on each unseen seed: the demonstration's queries plus a share of plain "
        "DAgger's final queries beyond them ([benchmark](benchmark.md), 'Equal budgets'); by area: the mean success "
        "over 16 log-spaced budgets up to DAgger's. Each cell: the best method (the controls and the oracle aside, "
        "chosen on these seeds) with its success, then its paired difference from the best gate at that budget (95% "
        "bootstrap interval; '=' where the best method is a gate), then the oracle's success where the run has it."
    )
    return "\n".join([note, "", *markdown_table(header, rows), *_stale_lines(context)])


def _at_budget(budget: dict[str, Any]) -> str:
    if budget["best"] is None:
        return "-"
    entries = {(e["method"], float(e["demo_fraction"])): e for e in budget["entries"]}
    best = entries[(budget["best"]["method"], float(budget["best"]["demo_fraction"]))]
    cell = f"{_curve(best)} {pct(best['success_rate'])}"
    gate = budget["best_gate"]
    against = [c for c in budget["comparisons"] if gate and c["against"] == gate["method"]]
    cell += f"; gate {_points(against[0])}" if against else "; gate ="
    oracle = [e for e in budget["entries"] if e["method"] in reference_methods()]
    return cell + (f"; oracle {pct(max(e['success_rate'] for e in oracle))}" if oracle else "")


def _by_area(reading: dict[str, Any]) -> str:
    if reading["best_auc"] is None:
        return "-"
    best = reading["best_auc"]
    area = {(a["method"], float(a["demo_fraction"])): a["mean"] for a in reading["auc"]}
    cell = f"{_curve(best)} {area[(best['method'], float(best['demo_fraction']))]:.2f}"
    oracle = [v for (m, _), v in area.items() if m in reference_methods()]
    return cell + (f"; oracle {max(oracle):.2f}" if oracle else "")


def _curve(entry: dict[str, Any]) -> str:
    share = float(entry["demo_fraction"])
    return method_label(entry["method"]) + ("" if share == 1.0 else f" ({share:.0%} of the demonstration)")


def _points(comparison: dict[str, Any]) -> str:
    return (
        f"{100 * comparison['difference']:+.0f} points ({100 * comparison['ci_low']:+.0f} to "
        f"{100 * comparison['ci_high']:+.0f})"
    )


#: Where figures drawn from the registry's data go, under the repository root.
DRAWN_FIGURES = Path("docs") / "figures"


def queries_figure(context: BlockContext, names: str, alt: str) -> str:
    """The benchmark figure of the first of the registry runs ``names`` (comma-separated) that has a
    benchmark summary, drawn in this code's style from that summary into ``docs/figures/<run>-queries.png``."""
    for name in names.split(","):
        found = context.runs.get(name)
        if found is not None and found.path("benchmark/summary.json").is_file():
            path = context.root / DRAWN_FIGURES / f"{name}-queries.png"
            if context.draw:
                plot_queries(found.json("benchmark/summary.json"), path)
            drawn = f"![{alt}]({context.link(path)})\n\n*Run `{name}`, drawn from its `benchmark/summary.json`.*"
            return "\n".join([drawn, *_stale_lines(context, [name])])
    return _missing(names.split(",")[0])


def _short(commit: str) -> str:
    """A commit's first 10 hex digits, keeping the ``+dirty`` mark of an uncommitted tree."""
    sha, dirty, _ = commit.partition("+dirty")
    return sha[:10] + dirty


def manifest_line(context: BlockContext, name: str) -> str:
    """What made registry run ``name``."""
    found = context.runs.get(name)
    if found is None:
        return _missing(name)
    m = found.manifest
    commits = sorted({c for stage in m["stages"].values() for c in stage.get("commits", [])})
    kernels = m["machine"]["kernels"]
    pins = "native kernels" if kernels == "native" else "pinned kernels"
    return (
        f"`{m['command']}`: {duration(m['wall_seconds'])} on {m['machine']['cpu']} "
        f"({', '.join(m['machine']['instruction_sets'])}; {pins}), {m['machine']['cores']} cores; beside it: "
        f"{m['beside']}. Stages made by {', '.join(_short(c) for c in commits) or 'unrecorded commits'}; "
        f"checked current at {_short(m['commit'])}; now {_status(context, name)}."
    )


#: Block kinds by name.
BLOCKS: dict[str, Callable[..., str]] = {
    "glance": glance,
    "runs": runs_table,
    "report": report_section,
    "figure": figure,
    "queries-figure": queries_figure,
    "budgets": budgets_table,
    "manifest": manifest_line,
}
