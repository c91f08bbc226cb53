"""Generated blocks: the results tables and figures of README.md and docs/, written from the registry.

A block is marked in a Markdown file by two comments; everything between them is generated::

    <!-- results: benchmark carracing-quick -->
    ...
    <!-- /results -->

The words after ``results:`` name a block kind of :data:`BLOCKS` and its
arguments. :func:`build` rewrites every block of the files from the registry; with ``check``, it
writes nothing and returns the blocks that differ from what it would write.
"""

from __future__ import annotations

import re
import shlex
import textwrap
from pathlib import Path
from typing import Callable, Sequence

from metadagger.errors import UserError
from metadagger.results import bench_blocks, calibration, tables
from metadagger.results.claims import claim
from metadagger.results.registry import REGISTRY, load_registry
from metadagger.results.staleness import registry_staleness
from metadagger.results.tables import BlockContext
from metadagger.results.verdict import verdict
from metadagger.utils.io import write_text

#: A block: its opening comment (kind and arguments), its generated body, its closing comment.
BLOCK = re.compile(
    r"^(?P<open><!-- results: (?P<spec>[^\n]*?) -->\n)(?P<body>.*?)(?P<close><!-- /results -->)", re.S | re.M
)

#: A fenced code block, whose text is never a block (a page may show the syntax).
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


#: Block kinds by name (:mod:`metadagger.results.tables`, :mod:`metadagger.results.verdict`,
#: :mod:`metadagger.results.claims`, :mod:`metadagger.results.bench_blocks`,
#: :mod:`metadagger.results.calibration`).
BLOCKS: dict[str, Callable[..., str]] = {
    "glance": tables.glance,
    "runs": tables.runs_table,
    "report": tables.report_section,
    "figure": tables.figure,
    "queries-figure": tables.queries_figure,
    "budgets": tables.budgets_table,
    "manifest": tables.manifest_line,
    "verdict": verdict,
    "claim": claim,
    "bench-arms": bench_blocks.arms_table,
    "bench-numerics": bench_blocks.numerics_table,
    "bench-compare": bench_blocks.compare_table,
    "bench-step": bench_blocks.step_table,
    "bench-lanes": bench_blocks.lanes_table,
    "bench-fit": bench_blocks.fit_table,
    "bench-env": bench_blocks.env_table,
    "bench-expert": bench_blocks.expert_block,
    "calibration": lambda context, task: calibration.calibration_table(context.root, task),
}

#: The column at which generated prose is wrapped (tables, headings and images are never wrapped).
WRAP = 100

#: A list item's marker: what its wrapped lines are indented under.
LIST_ITEM = re.compile(r"^(\s*(?:[-*]|\d+\.) )")


def wrap_prose(text: str, width: int = WRAP) -> str:
    """``text`` with each line of prose longer than ``width`` wrapped (a list item's continuation
    lines indented under its text); tables, headings, images, comments and fenced code as they are."""
    out, fenced = [], False
    for line in text.split("\n"):
        if line.startswith("```"):
            fenced = not fenced
        if fenced or len(line) <= width or line.lstrip().startswith(("|", "#", "!", "<", "```")):
            out.append(line)
            continue
        marker = LIST_ITEM.match(line)
        indent = " " * len(marker.group(1)) if marker else ""
        wrapped = textwrap.wrap(line, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False)
        if marker and len(wrapped) > 1 and wrapped[0] == marker.group(1).strip():  # a first word too long to follow it
            wrapped[:2] = [f"{wrapped[0]} {wrapped[1].lstrip()}"]
        out += wrapped
    return "\n".join(out)


def doc_files(root: str | Path = ".") -> list[Path]:
    """The files that may hold blocks: README.md and every Markdown page of docs/."""
    root = Path(root)
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def render_file(path: Path, context: BlockContext) -> tuple[str, list[str]]:
    """``path``'s text with every block regenerated, and the blocks whose body changed (as
    ``file:line kind args``)."""
    text = path.read_text()
    changed: list[str] = []
    fences = [m.span() for m in FENCE.finditer(text)]

    def regenerate(match: re.Match) -> str:
        if any(start <= match.start() < end for start, end in fences):
            return match.group(0)
        spec = match.group("spec").strip()
        words = shlex.split(spec)
        line = text.count("\n", 0, match.start()) + 1
        if not words or words[0] not in BLOCKS:
            raise UserError(
                f"{path}:{line}: block kind {words[0] if words else ''!r} is unknown; "
                f"expected one of {', '.join(sorted(BLOCKS))}"
            )
        try:
            body = wrap_prose(BLOCKS[words[0]](context.at(path), *words[1:])).rstrip("\n") + "\n"
        except (TypeError, ValueError) as exc:
            raise UserError(f"{path}:{line}: block {spec!r} cannot be written ({exc}); fix its arguments") from None
        if body != match.group("body"):
            changed.append(f"{path}:{line} {spec}")
        return match.group("open") + body + match.group("close")

    return BLOCK.sub(regenerate, text), changed


def build(
    root: str | Path = ".",
    *,
    registry: str | Path | None = None,
    check: bool = False,
    files: Sequence[Path] | None = None,
) -> list[str]:
    """Regenerate every block of README.md and docs/ under ``root`` from the registry (default
    ``root/results``); with ``check``, write nothing. Returns the blocks that differed."""
    root = Path(root)
    runs = load_registry(registry if registry is not None else root / REGISTRY)
    context = BlockContext(runs=runs, root=root, draw=not check, stale=registry_staleness(runs))
    changed: list[str] = []
    for path in files if files is not None else doc_files(root):
        if not path.is_file():
            continue
        text, differing = render_file(path, context)
        changed += differing
        if differing and not check:
            write_text(path, text)
    return changed
