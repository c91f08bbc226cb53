"""Generated blocks from the records kept in ``results/bench/`` (``metadagger bench ...``, ``results
compare`` and ``metadagger expert --out`` JSON), so that a page states a measured time, ratio, count
or success only as its record holds it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from metadagger.evaluation.expert import expert_table
from metadagger.evaluation.report.run import STAGE_ORDER, duration
from metadagger.evaluation.report.tables import markdown_table
from metadagger.results.compare import GROUP_COLUMNS
from metadagger.results.registry import REGISTRY
from metadagger.results.tables import BlockContext
from metadagger.utils.io import read_json

#: Where the speed records are kept, under the repository root.
BENCH = f"{REGISTRY}/bench"


def _record(context: BlockContext, file: str, what: str) -> tuple[Path, Any]:
    """The record ``file`` of ``results/bench/`` and its path; a missing file is a ``ValueError``."""
    path = context.root / BENCH / file
    if not path.is_file():
        raise ValueError(f"{BENCH}/{file} does not exist")
    return path, read_json(path, f"the {what} {BENCH}/{file}")


def _fields(record: Any, file: str, fields: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(record, dict) or any(field not in record for field in fields):
        raise ValueError(f"{BENCH}/{file} lacks one of {', '.join(fields)}")
    return record


def _link(context: BlockContext, path: Path) -> str:
    return f"[`{path.name}`]({context.link(path)})"


def arms_table(context: BlockContext, file: str) -> str:
    """A record of whole runs side by side (``bench reproduce``: ``arms``, each with its stages'
    seconds and its largest process's peak memory): a row per arm with each stage's time (a stage
    no arm ran is left out), their sum, the first arm's sum over this one's, and the peak; then what
    ran beside, as recorded."""
    path, record = _record(context, file, "speed record")
    arms: Any = record.get("arms") if isinstance(record, dict) else None
    if (
        not isinstance(arms, dict)
        or not arms
        or not all(isinstance(a, dict) and isinstance(a.get("stages"), dict) for a in arms.values())
    ):
        raise ValueError(f"{BENCH}/{file} holds no arms with stage seconds")
    named = {stage for arm in arms.values() for stage, seconds in arm["stages"].items() if seconds > 0}
    stages = [s for s in STAGE_ORDER if s in named] + sorted(named - set(STAGE_ORDER))
    totals = {name: sum(arm["stages"].values()) for name, arm in arms.items()}
    first = next(iter(totals.values()))
    rows = [
        (
            f"`{name}`" + (f" ({arm['commit']})" if arm.get("commit") and arm["commit"] not in name else ""),
            *(duration(arm["stages"][s]) if s in arm["stages"] else "-" for s in stages),
            duration(totals[name]),
            f"{first / totals[name]:.2f}x",
            f"{arm['peak_memory_mb']:,.0f} MB" if "peak_memory_mb" in arm else "-",
        )
        for name, arm in arms.items()
    ]
    header = ("arm", *stages, "all stages", "speed-up", "peak memory")
    note = (
        f"*From {_link(context, path)}: each stage's wall time, the first arm's sum over each arm's "
        "(speed-up), the largest process's peak resident memory."
        + (f" Beside them: {record['beside']}.*" if record.get("beside") else "*")
    )
    return "\n".join(markdown_table(header, rows) + ["", note])


def lanes_table(context: BlockContext, *files: str) -> str:
    """``bench lanes`` and ``bench pairs --lanes`` records, a row per lane width: what was timed (one
    benchmark seed in one process, or the pair seeds with 2 workers), the wall seconds, the speed-up
    over width 1 and, for a benchmark seed, the process's peak resident memory."""
    if not files:
        raise ValueError("bench-lanes needs at least one record")
    rows = []
    for file in files:
        path, record = _record(context, file, "lanes record")
        if isinstance(record, dict) and "widths" in record:
            record = _fields(record, file, ("seed", "widths", "speedup_wall"))
            timed = f"benchmark seed {record['seed']}, one process"
            widths = {int(w): entry for w, entry in record["widths"].items()}
            for width in sorted(widths):
                entry = widths[width]
                speedup = record["speedup_wall"][str(width)]
                peak = f"{entry['worker_peak_rss_mb']:,.0f} MB"
                rows.append(
                    (_link(context, path), timed, width, f"{entry['wall_seconds']:.1f}", f"{speedup:.2f}x", peak)
                )
        else:
            record = _fields(record, file, ("seeds", "seconds", "lanes", "lanes_speedup"))
            timed = f"{record['seeds']} pair seeds, 2 workers"
            rows.append((_link(context, path), timed, 1, f"{record['seconds']['2']:.1f}", "1.00x", "-"))
            for width in sorted(record["lanes"], key=int):
                seconds, speedup = record["lanes"][width]["seconds"], record["lanes_speedup"][width]
                rows.append((_link(context, path), timed, int(width), f"{seconds:.1f}", f"{speedup:.2f}x", "-"))
    header = ("record", "timed", "lanes", "wall seconds", "speed-up", "peak memory")
    note = "*Each record's widths measured one after the other on one machine; its `machine` block holds the load.*"
    return "\n".join(markdown_table(header, rows) + ["", note])


#: What a ``bench numerics`` record must hold.
NUMERICS_FIELDS = (
    "task",
    "width",
    "states",
    "actions_changed",
    "share_changed",
    "largest_output_difference",
)


def numerics_table(context: BlockContext, *files: str) -> str:
    """``bench numerics`` records, a row each: the task, the lane width, the states compared, the
    actions the lanes' batched forwards changed against batch 1 (a class, or any bit of a
    continuous action), and each state's largest output difference: median, 99th percentile, maximum."""
    if not files:
        raise ValueError("bench-numerics needs at least one record")
    rows = []
    for file in files:
        path, record = _record(context, file, "numerics record")
        record = _fields(record, file, NUMERICS_FIELDS)
        median, p99 = (record.get(f"{q}_output_difference") for q in ("median", "p99"))
        rows.append(
            (
                _link(context, path),
                f"`{record['task']}`",
                record["width"],
                f"{record['states']:,}",
                f"{record['actions_changed']:,} ({record['share_changed']:.2%})",
                *("-" if q is None else f"{q:.1e}" for q in (median, p99)),
                f"{record['largest_output_difference']:.1e}",
            )
        )
    header = ("record", "task", "lanes", "states", "actions changed", "median", "99th percentile", "largest")
    note = (
        "*pi\\*'s outputs on the states of its own episodes at batch 1 and in lanes of the width: the actions "
        "that differ, and each state's largest output difference (median, 99th percentile, largest over the states; "
        "'-': not in the record).*"
    )
    return "\n".join(markdown_table(header, rows) + ["", note])


def compare_table(context: BlockContext, *files: str) -> str:
    """``results compare`` records: a row each with the new run against the old one it was compared
    with, the success rates both hold, how many leave the old rate's 95% interval and the groups only
    the new run holds; then, a line a record, the rates that left their interval."""
    if not files:
        raise ValueError("bench-compare needs at least one record")
    rows, moved = [], []
    for file in files:
        path, record = _record(context, file, "comparison")
        record = _fields(record, file, ("new", "old", "rows", "outside", "only_new"))
        rows.append(
            (
                _link(context, path),
                f"`{record['new']}` against `{record['old']}`",
                len(record["rows"]),
                len(record["outside"]),
                len(record["only_new"]),
            )
        )
        if record["outside"]:
            moved.append(f"- `{record['new']}`: " + "; ".join(_moved(r) for r in record["outside"]) + ".")
    header = ("record", "runs", "rates in both", "outside the old 95% interval", "groups only in the new")
    return "\n".join(markdown_table(header, rows) + (["", *moved] if moved else []))


#: How a line names a compared row's group columns (:data:`~metadagger.results.compare.GROUP_COLUMNS`).
GROUP_NAMES = {"setting": "setting", "demo_fraction": "demonstration share"}


def _moved(row: dict[str, Any]) -> str:
    """One rate that left its old interval: where it stands, old -> new successes."""
    group = ", ".join(f"{GROUP_NAMES[key]} {row[key]}" for key in GROUP_COLUMNS if row.get(key))
    where = f"{row['table']} {row['column']} of `{row['method']}`" + (f" ({group})" if group else "")
    return f"{where}: {row['old'][0]}/{row['old'][1]} -> {row['new'][0]}/{row['new'][1]}"


#: The parts of a laned step a ``bench step`` record times, in the order a table shows them.
STEP_PARTS = (
    ("env_step", "the env's own step (physics and rendering)"),
    ("expert_labels", "the expert's label of every state"),
    ("trunk_forward", "pi*'s trunk, one forward for the live lanes"),
    ("rest_of_the_step", "the rest (the batch, the heads' actions, recording)"),
)


def _padding(record: dict[str, Any]) -> str:
    """The rows the trunk computed beyond the live lanes' (a step padded to a checked shape)."""
    rows, live = record["trunk_rows"], record["env_steps"]
    return f" on {rows:,} rows ({(rows - live) / rows:.0%} of them padding)" if rows else ""


def step_table(context: BlockContext, file: str) -> str:
    """A ``bench step`` record: each part of a laned benchmark step in milliseconds per env step,
    its share of the step and the step's time over the env's own; the head-only fits between
    rollouts beside it; then the seed, the width and the load the record was made under."""
    path, record = _record(context, file, "step record")
    record = _fields(record, file, ("per_env_step_ms", "step_over_env", "width", "seed", "env_steps"))
    per_step = record["per_env_step_ms"]
    if (
        not isinstance(per_step, dict)
        or any(key not in per_step for key, _ in STEP_PARTS)
        or "lanes_step" not in per_step
    ):
        raise ValueError(f"{BENCH}/{file} lacks a part of the step in per_env_step_ms")
    whole, env = per_step["lanes_step"], per_step["env_step"]
    rows = [(name, f"{per_step[key]:.2f}", f"{per_step[key] / whole:.0%}", "") for key, name in STEP_PARTS]
    rows.append(("**a laned step**", f"{whole:.2f}", "100%", f"{whole / env:.2f}x"))
    if "head_fits" in per_step:
        rows.append(("head-only fits between rollouts (beside the step)", f"{per_step['head_fits']:.2f}", "-", ""))
    header = ("part", "ms per env step", "share of the step", "over the env's own")
    load = (record.get("machine") or {}).get("load_avg_1min")
    run = Path(str(record.get("run", "the run"))).name
    note = (
        f"*From {_link(context, path)}: benchmark seed {record['seed']} of `{run}` at "
        f"{record['width']} lanes, {record['env_steps']:,} env steps"
        + (f", {record['trunk_forwards']:,} trunk forwards" if "trunk_forwards" in record else "")
        + (_padding(record) if "trunk_rows" in record else "")
        + (f"; the 1-minute load average at its end {load:.1f}." if isinstance(load, (int, float)) else ".")
        + "*"
    )
    return "\n".join(markdown_table(header, rows) + ["", note])


#: The parts of a whole-network fit's CPU time a ``bench fit`` record holds, in a table's order.
FIT_PARTS = (
    ("convolutions_forward", "convolutions forward"),
    ("convolutions_backward", "convolutions backward"),
    ("rest", "the rest"),
)


def _fit_steps(record: dict[str, Any]) -> str:
    """A fit's milliseconds per Adam step at each batch_shards timed, with the record's speed-up over
    the fewest (1.00x where it timed the preset's count alone)."""
    at = record.get("cpu_s_per_step_at_shards") or {str(record["batch_shards"]): record["cpu_s_per_step"]}
    speedups = record.get("speedup_over_fewest_shards") or {}
    return ", ".join(f"{at[c] * 1000:.1f} at {c} ({speedups.get(c, 1.0):.2f}x)" for c in sorted(at, key=int))


def fit_table(context: BlockContext, *files: str) -> str:
    """``bench fit`` records, a row each: pi*'s whole-network fit of a task's preset, its batch and
    batch_shards, the CPU's milliseconds per Adam step at each batch_shards timed (with the speed-up
    over the fewest), where a CPU step's time goes, and the GPU's step where the record has one."""
    if not files:
        raise ValueError("bench-fit needs at least one record")
    rows = []
    for file in files:
        path, record = _record(context, file, "fit record")
        record = _fields(record, file, ("task", "preset", "batch_size", "batch_shards", "cpu_s_per_step"))
        shares = record.get("cpu_time_shares") or {}
        gpu = (
            f"{record['gpu_s_per_step'] * 1000:.1f} ({record['gpu_speedup']:.1f}x the CPU's)"
            if "gpu_s_per_step" in record
            else "-"
        )
        rows.append(
            (
                _link(context, path),
                f"`{record['task']}` {record['preset']}",
                record["batch_size"],
                record["batch_shards"],
                _fit_steps(record),
                *(f"{shares[key]:.0%}" if key in shares else "-" for key, _ in FIT_PARTS),
                gpu,
            )
        )
    header = (
        "record",
        "pi*'s fit",
        "batch",
        "preset's shards",
        "CPU ms per step at shards (speed-up)",
        *(name for _, name in FIT_PARTS),
        "GPU ms per step",
    )
    note = (
        "*Adam steps on random frames of the task's shape, each batch_shards timed one after the other on one "
        "machine, one torch thread a shard; the shares are of the op time of a fit at one shard (torch's "
        "profiler, at most 20 steps); the record's `machine` block holds the load.*"
    )
    return "\n".join(markdown_table(header, rows) + ["", note])


def env_table(context: BlockContext, *files: str) -> str:
    """``bench env`` records, a row each: the env timed and the one it is timed against, each one's
    steps per second, the time of a step over the other's (by rate, and by median step time, which
    the machine's other load moves less), whether both gave the same rewards on the same actions,
    and the machine's 1-minute load average at the record's end."""
    rows, links = [], []
    for file in files:
        path, record = _record(context, file, "env record")
        record = _fields(record, file, ("ours", "upstream", "ratio", "ratio_of_medians", "identical_rewards"))
        ours, other = record["ours"], record["upstream"]
        rows.append(
            (
                f"`{ours['id']}`",
                f"`{other['id']}`",
                f"{ours['steps_per_s']:.0f} / {other['steps_per_s']:.0f}",
                f"{1 / record['ratio']:.2f}x",
                f"{1 / record['ratio_of_medians']:.2f}x",
                "yes" if record["identical_rewards"] else "no",
                _load((record.get("machine") or {}).get("load_avg_1min")),
            )
        )
        links.append(_link(context, path))
    header = ("env", "against", "steps per second", "step time, by rate", "by median", "same rewards", "load")
    note = f"*From {', '.join(links)}: both envs on the same seeds and actions, taking turns of 50 steps.*"
    return "\n".join(markdown_table(header, rows) + ["", note])


def _load(value: Any) -> str:
    return f"{value:.1f}" if isinstance(value, (int, float)) else "-"


def expert_block(context: BlockContext, file: str) -> str:
    """A record of ``metadagger expert --out``: the command that made it, then the expert's success
    on its seeds (95% Wilson interval), mean reward and episode lengths."""
    path, record = _record(context, file, "expert record")
    record = _fields(record, file, ("command", "rows"))
    return f"`{record['command']}` ({_link(context, path)}):\n\n{expert_table(record['rows'])}"
