"""The ``claim`` blocks: the findings' claims, one line per run, each with the numbers that decide it.

``<!-- results: claim KIND RUNS -->`` writes, for each run of ``RUNS`` (comma-separated), one list
item: the run (linked to its full report in the registry, marked where stale), the two or three
paired comparisons the claim ``KIND`` rests on (difference in points with its 95% interval), and
what they show, worded from the intervals alone:

- ``mappers``: the best MDM mapper (zero queries) against pi*'s head, mean-DA and BC refitted.
- ``refits``: BC refitted and DAgger, each after its last round, against BC: does a refit keep
  what BC had?
- ``labels``: DAgger after its last round against BC refitted: what DAgger's labels add over its
  refits' training alone; where the run has DART, also against DART at DAgger's labels: asking on
  the learner's states against asking for more (perturbed) demonstrations.
- ``oracle``: the learner's-mistakes rule (the oracle, a reference) against the best gate.
- ``gates``: the gate setting that reaches DAgger's success (its last round) with the fewest mean
  labels, and it against the random gate's cheapest setting that spends no fewer, paired: does
  choosing where to ask beat asking anywhere? (Read at each seed's own budget, a random setting
  just above the gate's labels would count as BC and flatter the gate.)
- ``coverage``: whether the seeds' coverage gap predicts a MetaL method's gain over its constant
  twin (Spearman's rho with its 95% interval): how many comparisons have an interval above 0 and
  below, how many each way chance alone would give, the highest rho and, where some lie below 0,
  the lowest (each one is in the run's report).

A run with confirmation seeds (``benchmark/confirm/``) gets a second item nested under its first,
the same claim read on them; for ``coverage`` a third, the comparisons whose rho is above 0 on
both. The runs without the rows a claim reads (or not in the registry yet) are named in one line.
"""

from __future__ import annotations

from typing import Any, Callable

from metadagger.evaluation.benchmark.coverage import rank_interval
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import BC_REFIT, DART, MDM_PREFIX, gated_methods, reference_methods
from metadagger.evaluation.benchmark.summary import last_round, refit_check
from metadagger.evaluation.paired import paired_comparison, verdict
from metadagger.evaluation.rows import read_csv
from metadagger.results.names import CONTROLS, SHORT_NAMES, difference_points, reference_label, with_share
from metadagger.results.registry import RegistryRun
from metadagger.results.tables import (
    SEED_SETS,
    BlockContext,
    best_entry,
    run_names,
    seed_set_item,
    whole_entries,
)

#: What a claim reads of one run's seed set (its benchmark folder, ``benchmark`` or
#: ``benchmark/confirm``): its line's text, or None where the set lacks the rows it needs.
Reader = Callable[[RegistryRun, str], "str | None"]

#: What each verdict of a comparison says, by claim.
SAYS = {
    "refits": {"better": "above BC", "worse": "loses what BC had", "no difference shown": "not shown below BC"},
    "labels": {
        "better": "the labels add to the training",
        "worse": "below BC refitted",
        "no difference shown": "the labels not shown to add",
    },
    "dart": {
        "better": "the learner's states above more demonstrations",
        "worse": "below DART",
        "no difference shown": "not shown above more demonstrations",
    },
    "gates": {
        "better": "above random",
        "worse": "below random",
        "no difference shown": "not shown above random",
    },
    "oracle": {
        "better": "the rule above the best gate",
        "worse": "the best gate above the rule",
        "no difference shown": "neither shown better",
    },
}


def claim(context: BlockContext, kind: str, names: str = "") -> str:
    """One list item per run of ``names`` (comma-separated; default every canonical run, the paper
    presets first) with the numbers that decide claim ``kind``; then one line naming the runs
    without the rows it reads."""
    if kind not in CLAIMS:
        raise ValueError(f"claim {kind!r} is not one of {', '.join(CLAIMS)}")
    lines, without = [], []
    for name in run_names(names):
        found = context.runs.get(name)
        made = []
        for seeds, folder in SEED_SETS if found else ():
            text = CLAIMS[kind](found, folder) if found.path(f"{folder}/summary.json").is_file() else None
            if text is not None:
                named = "" if folder == SEED_SETS[0][1] else seeds
                made.append(f"{seed_set_item(context, found, first=not made, named=named)}: {text}")
        both = ON_BOTH[kind](found) if kind in ON_BOTH and len(made) == 2 else None
        if both is not None:
            made.append(f"{seed_set_item(context, found, first=False, named='both seed sets')}: {both}")
        if not made:
            without.append(f"`{name}`" + ("" if found else " (not in the registry yet)"))
        lines += made
    if without:
        lines += ["", f"*Without the rows this claim reads: {', '.join(without)}.*"]
    return "\n".join(lines)


def _count(entry: dict[str, Any], *, queries: bool = True) -> str:
    """successes/seeds, at mean queries per seed."""
    count = f"{entry['successes']}/{entry['seeds']}"
    return count + (f" at {entry['mean_queries']:,.0f} queries" if queries else "")


def _named(entry: dict[str, Any]) -> str:
    setting = f" {entry['setting']}" if entry["setting"] else ""
    return f"{method_label(entry['method'])}{setting}"


def _found(summary: dict[str, Any], entry: dict[str, Any], against: str) -> dict[str, Any] | None:
    """The summary's paired comparison of ``entry`` with reference method ``against``, if made."""
    for c in summary.get("comparisons", []):
        if (c["method"], c["setting"], float(c["demo_fraction"])) == (
            entry["method"],
            entry["setting"],
            float(entry.get("demo_fraction", 1.0)),
        ) and c["against"] == against:
            return c
    return None


#: How a mapper claim words each paired verdict against a reference, in the order it names them.
_VERDICTS = {"better": "better than", "no difference shown": "not shown better than", "worse": "below"}


def _mappers(found: RegistryRun, folder: str) -> str | None:
    summary = found.json(f"{folder}/summary.json")
    mapped = [
        e
        for e in whole_entries(summary["entries"])
        if e["method"].startswith(MDM_PREFIX) and e["method"] not in CONTROLS
    ]
    if not mapped:
        return None
    best = min(mapped, key=lambda e: (-e["success_rate"], e["method"]))
    made = {a: c for a in (*CONTROLS, BC_REFIT) if (c := _found(summary, best, a)) is not None}
    parts = [f"against {SHORT_NAMES[a]} {difference_points(c)}" for a, c in made.items()]
    read = {kind: [SHORT_NAMES[a] for a, c in made.items() if verdict(c) == kind] for kind in _VERDICTS}
    if len(read["better"]) == len(made):
        says = "better than every one"
    else:
        says = "; ".join(f"{words} {', '.join(read[kind])}" for kind, words in _VERDICTS.items() if read[kind])
    return (
        f"best mapper {method_label(best['method'])} {_count(best, queries=False)}, " + "; ".join(parts) + f": {says}."
    )


def _refits(found: RegistryRun, folder: str) -> str | None:
    if not found.path(f"{folder}/queries.csv").is_file():
        return None
    checks = refit_check(read_csv(found.path(f"{folder}/queries.csv")))
    if not checks:
        return None
    parts = [
        f"{SHORT_NAMES[c['method']]} after {c['setting']} rounds {difference_points(c)} against BC, "
        f"{SAYS['refits'][verdict(c)]}"
        for c in checks
    ]
    return "; ".join(parts) + "."


def _labels(found: RegistryRun, folder: str) -> str | None:
    summary = found.json(f"{folder}/summary.json")
    dagger = last_round(whole_entries(summary["entries"]))
    refit = [e for e in whole_entries(summary["entries"]) if e["method"] == BC_REFIT]
    c = _found(summary, dagger, BC_REFIT) if dagger else None
    if c is None or not refit:
        return None
    line = (
        f"DAgger after {dagger['setting']} rounds {_count(dagger)}, BC refitted {_count(refit[0])}: "
        f"{difference_points(c)}, {SAYS['labels'][verdict(c)]}"
    )
    dart = last_round(whole_entries(summary["entries"]), method=DART)
    against_dart = _found(summary, dagger, DART) if dart else None
    if against_dart is not None:
        line += (
            f"; DART at DAgger's labels {_count(dart, queries=False)}: {difference_points(against_dart)}, "
            f"{SAYS['dart'][verdict(against_dart)]}"
        )
    return line + "."


def _oracle(found: RegistryRun, folder: str) -> str | None:
    summary = found.json(f"{folder}/summary.json")
    entries = whole_entries(summary["entries"])
    gates = [r for r in summary.get("references", []) if r["method"] in gated_methods()]
    oracle = [e for e in entries if e["method"] in reference_methods()]
    if not gates or not oracle:
        return None
    rule = best_entry(oracle)
    gate = next(e for e in entries if (e["method"], e["setting"]) == (gates[0]["method"], gates[0]["setting"]))
    c = _found(summary, rule, gate["method"])
    if c is None:
        return None
    return (
        f"the rule at {rule['setting']} {_count(rule)}, the best gate ({_named(gate)}) {_count(gate)}: "
        f"{difference_points(c)}, {SAYS['oracle'][verdict(c)]}."
    )


#: The gate that asks anywhere: the one every other gate must beat at equal labels.
RANDOM_GATE = "dagger-random"


def _gates(found: RegistryRun, folder: str) -> str | None:
    summary = found.json(f"{folder}/summary.json")
    entries = whole_entries(summary["entries"])
    dagger = last_round(entries)
    gates = [e for e in entries if e["method"] in gated_methods()]
    if dagger is None or not gates or not found.path(f"{folder}/queries.csv").is_file():
        return None
    reaching = [e for e in gates if e["successes"] >= dagger["successes"]]
    # the cheapest setting that reaches DAgger's success; else the most successful, cheapest first
    gate = min(
        reaching or gates,
        key=lambda e: (0 if reaching else -e["successes"], e["mean_queries"], e["method"], e["setting"]),
    )
    reach = (
        f"{_named(gate)} reaches DAgger's {_count(dagger, queries=False)} with the fewest labels, "
        if reaching
        else f"no gate reaches DAgger's {_count(dagger, queries=False)}; the closest, {_named(gate)}, has "
    )
    line = f"{reach}{_count(gate)} (DAgger at {dagger['mean_queries']:,.0f})"
    if gate["method"] == RANDOM_GATE:
        return line + ", the random gate itself."
    no_fewer = [e for e in gates if e["method"] == RANDOM_GATE and e["mean_queries"] >= gate["mean_queries"]]
    if not no_fewer:
        return line + "; no setting of the random gate spends as many labels."
    random = min(no_fewer, key=lambda e: e["mean_queries"])
    rows = [r for r in read_csv(found.path(f"{folder}/queries.csv")) if float(r["demo_fraction"]) == 1.0]
    by_seed = [
        {r["seed"]: r for r in rows if (r["method"], str(r["setting"])) == (e["method"], e["setting"])}
        for e in (gate, random)
    ]
    seeds = sorted(set(by_seed[0]) & set(by_seed[1]))
    a, b = ({key: [side[s][key] for s in seeds] for key in ("success", "reward")} for side in by_seed)
    c = paired_comparison(a["success"], b["success"], a["reward"], b["reward"])
    return (
        f"{line}; against the random gate spending no fewer ({random['setting']}: {_count(random)}) "
        f"{difference_points(c)}, {SAYS['gates'][verdict(c)]}."
    )


def _coverage(found: RegistryRun, folder: str) -> str | None:
    compared = _compared(found, folder)
    ranked = _ranked(compared)
    if not ranked:
        return None
    read = []
    for (method, fraction, twin), (rho, low, high) in ranked.items():
        pair = f"{with_share(method_label(method), fraction)} against {reference_label(method, twin, 1.0)}"
        read.append((rho, f"{rho:+.2f} ({low:+.2f} to {high:+.2f}), {pair}", low, high))
    above = sum(low > 0 for _, _, low, _ in read)
    below = sum(high < 0 for _, _, _, high in read)
    unranked = len(compared) - len(ranked)
    counted = (
        f"rho above 0 in {above} of {len(read)} comparison{'s' if len(read) > 1 else ''}, below in {below} "
        f"({0.025 * len(read):.1f} each way by chance" + (f"; {unranked} more without a rank)" if unranked else ")")
    )
    extremes = sorted(read, key=lambda r: r[0])
    lowest = f"; lowest {extremes[0][1]}" if below else ""  # it decides nothing where none lies below 0
    shown = extremes[-1][1] if len(read) == 1 else f"highest {extremes[-1][1]}{lowest}"
    return f"over {compared[0]['seeds']} seeds, {counted}; {shown}."


def _coverage_on_both(found: RegistryRun) -> str | None:
    """The comparisons whose rho lies above 0 on both seed sets, by method; None without both."""
    sets = [_ranked(_compared(found, folder)) for _, folder in SEED_SETS]
    if not all(sets):
        return None
    both = [key for key, (_, low, _) in sets[0].items() if low > 0 and key in sets[1] and sets[1][key][1] > 0]
    if not both:
        return "rho above 0 on both in no comparison."
    methods = dict.fromkeys(with_share(method_label(method), fraction) for method, fraction, _ in both)
    plural = "s, each" if len(both) > 1 else ","
    return f"rho above 0 on both in {len(both)} comparison{plural} of {' or '.join(methods)} against a constant twin."


def _compared(found: RegistryRun, folder: str) -> list[dict[str, Any]]:
    """A seed set's coverage comparisons (a MetaL curve against a constant twin); [] without."""
    if not found.path(f"{folder}/summary.json").is_file():
        return []
    return (found.json(f"{folder}/summary.json").get("coverage") or {}).get("methods", [])


def _ranked(compared: list[dict[str, Any]]) -> dict[tuple[str, float, str], tuple[float, float, float]]:
    """rho with its 95% interval, by (method, demonstration share, twin), for the comparisons with a rank."""
    ranked = {}
    for c in compared:
        if c["rho"] is not None:
            low, high = rank_interval(c["rho"], c["seeds"]) or (float("nan"), float("nan"))
            ranked[(c["method"], float(c["demo_fraction"]), c["against"])] = (c["rho"], low, high)
    return ranked


#: The claims by kind.
CLAIMS: dict[str, Reader] = {
    "mappers": _mappers,
    "refits": _refits,
    "labels": _labels,
    "oracle": _oracle,
    "gates": _gates,
    "coverage": _coverage,
}

#: The claims that read a run's two seed sets together, in an item nested after theirs.
ON_BOTH: dict[str, Callable[[RegistryRun], "str | None"]] = {"coverage": _coverage_on_both}
