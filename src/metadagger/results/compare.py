"""Old against new: every success rate of one run's tables beside the 95% interval of another's.

A change of numerics (``NUMERICS``) moves a run's numbers; :func:`compare_runs` says by how much.
For each table both run folders (or registry runs) hold, each method (with its setting and share
of the demonstration) and each success column, it gives the old and the new successes and whether
the new rate lies inside the old rate's 95% Wilson interval. Methods renamed since the old run
was made are read under their names now.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

from metadagger.errors import UserError
from metadagger.evaluation.rows import read_csv
from metadagger.imitation.metrics import wilson_interval

#: The tables compared, relative to a run folder (or a registry run).
TABLES = ("eval/mdm.csv", "eval/oneshot.csv", "eval/mdi.csv", "benchmark/queries.csv")

#: Method names of older runs, by table, under their names now.
RENAMED_METHODS = {"eval/mdi.csv": {"dagger-bc": "dagger-bc-init", "dagger": "dagger-xavier"}}

#: The columns that, with ``method``, name a row's group where a table has them.
GROUP_COLUMNS = ("setting", "demo_fraction")


def _counts(rows: list[dict[str, Any]], table: str, column: str) -> dict[tuple[str, ...], tuple[int, int]]:
    renamed = RENAMED_METHODS.get(table, {})
    counts: dict[tuple[str, ...], list[int]] = defaultdict(lambda: [0, 0])
    for row in rows:
        method = renamed.get(row["method"], row["method"])
        key = (method, *(str(row.get(c, "")) for c in GROUP_COLUMNS))
        counts[key][0] += bool(row[column])
        counts[key][1] += 1
    return {key: (k, n) for key, (k, n) in counts.items()}


def compare_runs(old: str | Path, new: str | Path) -> dict[str, Any]:
    """Every shared table's success rates of run ``new`` against run ``old``'s 95% intervals.

    Returns:
        ``rows``: one per table, success column and group present in both, with ``old`` and
        ``new`` as ``[successes, n]``, the old interval and ``inside``; ``outside``: the rows
        whose new rate leaves the old interval; ``only_old``/``only_new``: groups in one run alone.

    Raises:
        UserError: either folder is missing, or the two share no table.
    """
    old, new = Path(old), Path(new)
    for folder in (old, new):
        if not folder.is_dir():
            raise UserError(f"no run folder at {folder}; pass two run folders or registry runs (results/<name>)")
    tables = [t for t in TABLES if (old / t).is_file() and (new / t).is_file()]
    if not tables:
        raise UserError(f"{old} and {new} share none of the tables {', '.join(TABLES)}; pass two runs of one preset")
    rows: list[dict[str, Any]] = []
    only_old: list[str] = []
    only_new: list[str] = []
    for table in tables:
        old_rows, new_rows = read_csv(old / table), read_csv(new / table)
        shared = set(new_rows[0]) if new_rows else set()
        columns = [c for c in (old_rows[0] if old_rows else ()) if c in shared and c.endswith("success")]
        for column in columns:
            before, after = _counts(old_rows, table, column), _counts(new_rows, table, column)
            only_old += [f"{table} {column} {'/'.join(k)}" for k in sorted(set(before) - set(after))]
            only_new += [f"{table} {column} {'/'.join(k)}" for k in sorted(set(after) - set(before))]
            for key in sorted(set(before) & set(after)):
                (k_old, n_old), (k_new, n_new) = before[key], after[key]
                low, high = wilson_interval(k_old, n_old)
                rows.append(
                    {
                        "table": table,
                        "column": column,
                        "method": key[0],
                        **dict(zip(GROUP_COLUMNS, key[1:])),
                        "old": [k_old, n_old],
                        "new": [k_new, n_new],
                        "old_interval": [low, high],
                        "inside": low <= k_new / n_new <= high,
                    }
                )
    return {
        "old": str(old),
        "new": str(new),
        "rows": rows,
        "outside": [r for r in rows if not r["inside"]],
        "only_old": only_old,
        "only_new": only_new,
    }


def comparison_lines(comparison: dict[str, Any]) -> list[str]:
    """The comparison as a Markdown table (one row per group), then the rows outside their interval."""
    lines = [
        f"old: {comparison['old']}  new: {comparison['new']}",
        "",
        "| table | column | method | setting | demo share | old | new | old 95% interval | inside |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in comparison["rows"]:
        low, high = r["old_interval"]
        lines.append(
            f"| {r['table']} | {r['column']} | {r['method']} | {r.get('setting', '')} | {r.get('demo_fraction', '')} "
            f"| {r['old'][0]}/{r['old'][1]} | {r['new'][0]}/{r['new'][1]} | {low:.0%}-{high:.0%} "
            f"| {'yes' if r['inside'] else 'NO'} |"
        )
    outside = comparison["outside"]
    lines += ["", f"{len(outside)} of {len(comparison['rows'])} rates outside the old run's 95% interval."]
    for name, groups in (
        ("only in the old run", comparison["only_old"]),
        ("only in the new run", comparison["only_new"]),
    ):
        if groups:
            lines.append(f"{len(groups)} groups {name}: {', '.join(groups[:10])}{' ...' if len(groups) > 10 else ''}")
    return lines
