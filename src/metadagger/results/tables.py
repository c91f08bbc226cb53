"""The kinds of generated block (:mod:`metadagger.results.blocks`), each a function of the registry.

- ``glance``: every run's best MetaL DAgger method beside its controls (pi*'s head, mean-DA, BC
  refitted), then DAgger, the best gate and the oracle, each with its interval and queries per
  seed; the paper's figures.
- ``runs``: every canonical run: its arguments, wall time, CPU, what it shows.
- ``report RUN HEADING [ROW ...]``: the section of RUN's ``report.md`` under HEADING (its figures
  linked where they lie in the registry), or only its first table's rows ROW.
- ``figure RUNS PATH ALT``: an image of the first of RUNS that has it. RUNS: comma-separated run
  names, or a preset's name for every canonical run of it (:func:`run_names`).
- ``queries-figure RUNS ALT``: the benchmark figure of the first of RUNS, drawn from its summary.
- ``budgets [RUNS]``: the runs read at equal budgets and by the area under the curve.
- ``verdict RUNS``: whether a MetaL DAgger method beats every one of its references
  (:mod:`metadagger.results.verdict`).
- ``claim KIND RUNS``: one of the findings' claims, an item per run (:mod:`metadagger.results.claims`).
- ``manifest RUN``: what made RUN: commit, CPU and kernels, wall time, what ran beside.

A block about a run the registry does not hold yet says so, with the command that makes it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

from metadagger.evaluation.benchmark.figure import plot_queries
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import (
    BC_REFIT,
    DART,
    MDI_METHODS,
    gated_methods,
    metal_twins,
    reference_methods,
)
from metadagger.evaluation.benchmark.summary import budget_reading, last_round
from metadagger.evaluation.report.tables import markdown_table, pct
from metadagger.evaluation.rows import read_csv
from metadagger.results.names import CONTROLS, difference_points, with_share
from metadagger.results.registry import CANONICAL_RUNS, RegistryRun, canonical_run
from metadagger.results.staleness import stale_summary

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


def missing_run(name: str) -> str:
    """What a block says of a canonical run the registry does not hold yet: the commands that add it."""
    run = canonical_run(name)
    return (
        f"*Not in the registry yet: `{run.command}`, then `metadagger results add --out runs/{run.name} "
        f'--name {run.name} --beside "..."`.*'
    )


def _cell(entry: dict[str, Any] | None, *, queries: bool = True) -> str:
    """successes/seeds (95% interval) at mean queries per seed."""
    if entry is None:
        return "-"
    cell = f"{entry['successes']}/{entry['seeds']} ({_ci(entry['success_ci_low'], entry['success_ci_high'])})"
    return cell + (f" at {entry['mean_queries']:,.0f}" if queries else "")


def _ci(low: float, high: float) -> str:
    return f"{100 * low:.0f}-{100 * high:.0f}%"


def best_entry(entries: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The highest success, then the fewest queries; None for none."""
    return min(entries, key=lambda e: (-e["success_rate"], e["mean_queries"])) if entries else None


def whole_entries(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A benchmark summary's entries on the whole demonstration."""
    return [e for e in entries if float(e.get("demo_fraction", 1.0)) == 1.0]


def _labelled(entry: dict[str, Any] | None) -> str:
    if entry is None:
        return "-"
    setting = f" {entry['setting']}" if entry["setting"] else ""
    return f"{method_label(entry['method'])}{setting}: {_cell(entry)}"


def _glance_entries(found: RegistryRun) -> dict[str, Any]:
    """A run's benchmark entries on the whole demonstration, sorted into the glance's columns."""
    entries = whole_entries(found.json("benchmark/summary.json")["entries"])
    by_method = {e["method"]: e for e in entries}
    return {
        "metal": best_entry([e for e in entries if metal_twins(e["method"]) or e["method"] == MDI_METHODS[0]]),
        "pistar": by_method.get(CONTROLS[0]),
        "mean-da": by_method.get(CONTROLS[1]),
        "refit": by_method.get(BC_REFIT),
        "dagger": last_round(entries),
        "dart": last_round(entries, DART),
        "gate": best_entry([e for e in entries if e["method"] in gated_methods()]),
        "oracle": best_entry([e for e in entries if e["method"] in reference_methods()]),
        "seeds": max((e["seeds"] for e in entries), default=0),
    }


def glance(context: BlockContext) -> str:
    """The at-a-glance tables of the paper-preset runs, then of the quick ones: the best MetaL
    DAgger method beside its controls, then DAgger, the best gate and the oracle."""
    metal, queries = [], []
    for run in sorted(CANONICAL_RUNS, key=lambda r: r.preset != "paper"):
        found = context.runs.get(run.name)
        if found is None or not found.path("benchmark/summary.json").is_file():
            metal.append((f"`{run.name}`", "not run yet", "", "", "", ""))
            queries.append((f"`{run.name}`", "not run yet", "", "", ""))
            continue
        e = _glance_entries(found)
        name = _run_cell(context, run.name)
        controls = (_cell(e["pistar"], queries=False), _cell(e["mean-da"], queries=False), _cell(e["refit"]))
        metal.append((name, str(e["seeds"]), _labelled(e["metal"]), *controls))
        oracle = f"{e['oracle']['setting']}: {_cell(e['oracle'])}" if e["oracle"] else "-"
        dart = _cell(e["dart"]) if e["dart"] else "-"
        queries.append((name, _cell(e["dagger"]), dart, _labelled(e["gate"]), oracle))
    note = (
        "Seeds succeeded of the run's unseen seeds (95% Wilson interval) at mean expert queries per seed, "
        "demonstration included, one rollout per seed. Best MetaL DAgger: the best method that reads a learned "
        "mapper, or DAgger-MDI; pi*'s head and mean-DA use no query; BC refitted is w_BC refitted as DAgger refits "
        "it, with no new label; DART spends DAgger's labels on the expert's perturbed episodes (runs made before "
        "it have none); the oracle labels the learner's mistakes (a reference, not a ceiling). Each best "
        "is chosen on these seeds, which favours it: paired comparisons are in each run's report, what a 'stale' "
        "run departs from in docs/results.md."
    )
    paper = "; ".join(f"{task}: {figures}" for task, figures in PAPER_FIGURES.items())
    return "\n".join(
        [
            note,
            "",
            *markdown_table(("run", "seeds", "best MetaL DAgger", "pi*-head", "mean-DA", "BC refitted"), metal),
            "",
            f"The paper reports {paper}.",
            "",
            *markdown_table(
                ("run", "DAgger (last round)", "DART at its labels", "best gate", "reference: oracle"), queries
            ),
            *_stale_names(context),
        ]
    )


def runs_table(context: BlockContext) -> str:
    """Every canonical run: its arguments, wall time, CPU and what it shows."""
    rows = []
    for run in CANONICAL_RUNS:
        found = context.runs.get(run.name)
        wall = found.wall_time() if found else "not run yet"
        extra = run.command.split(f"--out runs/{run.name}", 1)[1].strip()
        cpu = found.manifest["machine"]["cpu"] if found else "-"
        rows.append(
            (
                f"`{run.name}`",
                run.task,
                run.preset,
                f"`{extra}`" if extra else "",
                wall,
                cpu,
                _status(context, run.name),
                run.shows,
            )
        )
    note = (
        "Each run is `metadagger reproduce --task TASK --preset PRESET --out runs/RUN` with the arguments shown. "
        "Wall time as measured, on the CPU named, with the other work the run's manifest names running beside it "
        "on the same cores (docs/results.md, 'What made each run'); on an idle machine a run takes less. Status: "
        "current, or stale with what departed (`setting: run's -> today's`): a stale run's numbers are those of "
        "the config and code that made it, kept and marked until its command is run again and `metadagger results "
        "add` takes the new folder (`metadagger results status` lists them)."
    )
    header = ("run", "task", "preset", "arguments", "wall time", "CPU", "status", "shows")
    return "\n".join([note, "", *markdown_table(header, rows)])


def _status(context: BlockContext, name: str) -> str:
    """ "current", "stale: what departed", or "-" for a run the registry does not hold."""
    if name not in context.runs:
        return "-"
    reasons = context.stale.get(name)
    return f"stale: {stale_summary(reasons)}" if reasons else "current"


def run_names(names: str = "") -> list[str]:
    """The canonical runs ``names``: comma-separated run names (each must be one), or a preset's name
    for every canonical run of that preset (``paper``); by default every one, the paper presets first."""
    if names in {run.preset for run in CANONICAL_RUNS}:
        runs = [run for run in CANONICAL_RUNS if run.preset == names]
    else:
        runs = [canonical_run(name) for name in names.split(",")] if names else list(CANONICAL_RUNS)
    return [run.name for run in sorted(runs, key=lambda r: r.preset != "paper")]


def run_item(context: BlockContext, found: RegistryRun) -> str:
    """A run at the head of a list item: its name linked to its full report, marked where stale."""
    stale = " (stale)" if context.stale.get(found.name) else ""
    return f"[`{found.name}`]({context.link(found.path('report/report.md'))}){stale}"


def _run_cell(context: BlockContext, name: str) -> str:
    """A run's name for a table's first column, marked where the run is stale."""
    return f"`{name}` (stale)" if context.stale.get(name) else f"`{name}`"


def _stale_names(context: BlockContext, names: list[str] | None = None) -> list[str]:
    """For a table of many runs whose rows mark the stale ones (:func:`_run_cell`): one line saying
    what the mark means, where any run of ``names`` (default every run of the registry) is stale."""
    if not any(context.stale.get(n) for n in (names if names is not None else context.runs)):
        return []
    return [
        "",
        "*(stale): made by a config or numerics other than today's; the runs table in docs/results.md and "
        "`metadagger results status` say what departed.*",
    ]


def _stale_lines(context: BlockContext, names: list[str] | None = None) -> list[str]:
    """One line per stale run of ``names`` (default: every run of the registry) naming what departed,
    after a blank line; nothing when all are current."""
    stale = [n for n in (names if names is not None else context.runs) if context.stale.get(n)]
    lines = [f"*Stale `{n}` (run's -> today's): {stale_summary(context.stale[n])}.*" for n in stale]
    return ["", *lines] if lines else []


def report_section(context: BlockContext, name: str, heading: str, *rows: str) -> str:
    """The section of run ``name``'s report under the heading that starts with ``heading`` (its
    body, to the next heading of the same or a higher level), figure links made to point into
    the registry.

    With ``rows``, only the section's first table: its header and the rows whose leading cells,
    joined by `` | ``, equal one of ``rows`` (``"MDM Ridge"``, or ``"DAgger | 3"`` for one setting),
    in the report's order. A ``columns=0,1,4`` among them keeps those columns only."""
    found = context.runs.get(name)
    if found is None:
        return missing_run(name)
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
    if rows:
        return "\n".join(
            [_table_rows(body, rows, f"registry run {name}'s section {heading!r}"), *_stale_lines(context, [name])]
        )
    return "\n".join([*body, *_stale_lines(context, [name])]).strip("\n")


def _table_rows(body: list[str], rows: Sequence[str], called: str) -> str:
    """The header of the first table in ``body`` and its rows chosen by ``rows`` (see :func:`report_section`)."""
    columns = [spec.removeprefix("columns=") for spec in rows if spec.startswith("columns=")]
    wanted = [spec for spec in rows if not spec.startswith("columns=")]
    start = next((i for i, line in enumerate(body) if line.startswith("|")), None)
    if start is None:
        raise ValueError(f"{called} has no table")
    table = list(itertools.takewhile(lambda line: line.startswith("|"), body[start:]))
    cells = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in table]
    keep = [int(i) for i in columns[0].split(",")] if columns else list(range(len(cells[0])))
    chosen = [row for row in cells[2:] if any(" | ".join(row[: spec.count(" | ") + 1]) == spec for spec in wanted)]
    missing = [spec for spec in wanted if not any(" | ".join(row[: spec.count(" | ") + 1]) == spec for row in chosen)]
    if missing:
        raise ValueError(f"{called} has no row {missing[0]!r}")
    lines = ["| " + " | ".join(row[i] for i in keep) + " |" for row in [cells[0], *chosen]]
    return "\n".join([lines[0], "|" + "---|" * len(keep), *lines[1:]])


def figure(context: BlockContext, names: str, path: str, alt: str) -> str:
    """An image of the first of the registry runs ``names`` (comma-separated) that has it, with
    the run it shows."""
    for name in names.split(","):
        found = context.runs.get(name)
        if found is not None and found.path(path).is_file():
            return "\n".join(
                [f"![{alt}]({context.link(found.path(path))})\n\n*Run `{name}`.*", *_stale_lines(context, [name])]
            )
    return missing_run(names.split(",")[0])


#: Equal-budget readings by the SHA-256 of the rows they were read from.
_READINGS: dict[str, dict[str, Any] | None] = {}


def rows_reading(path: Path) -> dict[str, Any] | None:
    """The equal-budget reading of the benchmark rows in ``path`` (``queries.csv``); None without the
    file or without DAgger rows. The same bytes are read once per process (the verdict and the
    budgets table both read every run's, and a copy of the registry reads as the registry)."""
    if not path.is_file():
        return None
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest not in _READINGS:
        _READINGS[digest] = budget_reading(read_csv(path))
    return _READINGS[digest]


#: A run's seed sets: its unseen seeds, then its confirmation seeds where it has them (the same
#: methods on a second set, fixed before any was read), each by its name and its benchmark folder.
SEED_SETS = (("unseen seeds", "benchmark"), ("confirmation seeds", "benchmark/confirm"))


def seed_set_item(context: BlockContext, found: RegistryRun, *, first: bool, named: str = "") -> str:
    """The head of a list item reading a run on one seed set: for its first set the run (linked,
    marked where stale), then ``, named`` where given; for the next, an item nested under it that
    starts with ``named``."""
    return (f"- {run_item(context, found)}" + (f", {named}" if named else "")) if first else f"  - {named}"


def budgets_table(context: BlockContext, names: str = "") -> str:
    """The canonical runs ``names`` (comma-separated; default every one) read at equal budgets, from
    each one's ``benchmark/queries.csv``: at each budget and by the area under the curve, the best
    method (the oracle and the controls aside), its paired difference from the best gate there, and
    the oracle's success beside it."""
    runs = run_names(names)
    rows = []
    for name in runs:
        found = context.runs.get(name)
        readings = [(s, f, rows_reading(found.path(f"{f}/queries.csv"))) for s, f in SEED_SETS] if found else []
        if not readings or readings[0][2] is None:
            rows.append((f"`{name}`", "not run yet" if found is None else "no DAgger rows", "", "", "", ""))
            continue
        for seeds, folder, reading in readings:
            if reading is None:
                continue
            cell = _run_cell(context, name) + ("" if folder == SEED_SETS[0][1] else f", {seeds}")
            rows += [(cell, f"+{b['share']:.0%}", *_at_budget(b)) for b in reading["budgets"]]
            rows.append((cell, "area", *_by_area(reading)))
    note = (
        "Every method read at the same spend on each unseen seed (and, in their own rows, each confirmation seed): "
        "the demonstration's queries plus a share of plain "
        "DAgger's final queries beyond them ([benchmark](benchmark.md), 'Equal budgets'); by area: the mean success "
        "over 16 log-spaced budgets up to DAgger's. At each: the best method (the controls and the oracle aside, "
        "chosen on these seeds), its success (or area), its paired difference from the best gate there (95% "
        "bootstrap interval, points; '=' where the best method is a gate), and the oracle's success where the run "
        "has it."
    )
    header = ("run", "budget", "best method", "success", "minus the best gate", "oracle")
    return "\n".join([note, "", *markdown_table(header, rows), *_stale_names(context, runs)])


def _at_budget(budget: dict[str, Any]) -> tuple[str, str, str, str]:
    if budget["best"] is None:
        return ("-", "", "", "")
    entries = {(e["method"], float(e["demo_fraction"])): e for e in budget["entries"]}
    best = entries[(budget["best"]["method"], float(budget["best"]["demo_fraction"]))]
    gate = budget["best_gate"]
    against = [c for c in budget["comparisons"] if gate and c["against"] == gate["method"]]
    oracle = [e for e in budget["entries"] if e["method"] in reference_methods()]
    return (
        with_share(method_label(best["method"]), best["demo_fraction"]),
        pct(best["success_rate"]),
        difference_points(against[0]) if against else "=",
        pct(max(e["success_rate"] for e in oracle)) if oracle else "-",
    )


def _by_area(reading: dict[str, Any]) -> tuple[str, str, str, str]:
    if reading["best_auc"] is None:
        return ("-", "", "", "")
    best = reading["best_auc"]
    area = {(a["method"], float(a["demo_fraction"])): a["mean"] for a in reading["auc"]}
    gates = [curve for curve in area if curve[0] in gated_methods()]
    gate = max(gates, key=lambda curve: area[curve]) if gates else None
    against = [
        c
        for c in reading["auc_comparisons"]
        if gate is not None
        and (c["against"], float(c["against_demo_fraction"])) == gate
        and (c["method"], float(c["demo_fraction"])) == (best["method"], float(best["demo_fraction"]))
    ]
    oracle = [v for (m, _), v in area.items() if m in reference_methods()]
    return (
        with_share(method_label(best["method"]), best["demo_fraction"]),
        f"{area[(best['method'], float(best['demo_fraction']))]:.2f}",
        difference_points(against[0]) if against else "=",
        f"{max(oracle):.2f}" if oracle else "-",
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
    return missing_run(names.split(",")[0])


def _short(commit: str) -> str:
    """A commit's first 10 hex digits, keeping the ``+dirty`` mark of an uncommitted tree."""
    sha, dirty, _ = commit.partition("+dirty")
    return sha[:10] + dirty


def manifest_line(context: BlockContext, name: str) -> str:
    """What made registry run ``name``."""
    found = context.runs.get(name)
    if found is None:
        return missing_run(name)
    m = found.manifest
    commits = sorted({c for stage in m["stages"].values() for c in stage.get("commits", [])})
    kernels = m["machine"]["kernels"]
    pins = "native kernels" if kernels == "native" else "pinned kernels"
    return (
        f"`{m['command']}`: {found.wall_time()} on {m['machine']['cpu']} "
        f"({', '.join(m['machine']['instruction_sets'])}; {pins}), {m['machine']['cores']} cores; beside it: "
        f"{m['beside']}. Stages made by {', '.join(_short(c) for c in commits) or 'unrecorded commits'}; "
        f"checked current at {_short(m['commit'])}; now {_status(context, name)}."
    )
