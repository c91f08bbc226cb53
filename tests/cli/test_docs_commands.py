"""The manuals name the command line and themselves as they are: every ``metadagger ...`` in
README.md and docs/ (an inline code span, or a line of a fenced block) names commands that exist and
options those commands take; the README's "Command line" block names every command and subcommand
there is; every command's help opens with a one-line summary (the line its group's listing shows);
and every pointer to a section of a manual (``docs/fetch.md, "The pairs"`` or
``([fetch](fetch.md), 'The pairs')``, in the code, the presets, the scripts, the examples or the
manuals) names a heading or a bold paragraph label of that manual."""

from __future__ import annotations

import inspect
import re
from pathlib import Path
from typing import Any

import pytest
import typer

from metadagger.cli.main import app

ROOT = Path(__file__).resolve().parents[2]
MANUALS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
COMMAND_LINE = typer.main.get_command(app)
INLINE = re.compile(r"`(metadagger [^`]+)`")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.M | re.S)
#: A pointer to a manual's section: the manual's file name, then its section's name in quotes.
POINTER = re.compile(r"([a-z_]+\.md)\)?,\s+(?:\"([^\"]+)\"|'([^']+)')")
POINTING = [
    *(p for p in (ROOT / "src").rglob("*") if p.suffix in {".py", ".yaml", ".js", ".html"}),
    *(ROOT / "scripts").glob("*"),
    *(ROOT / "examples").rglob("*.py"),
    *MANUALS,
]


def _mentions(text: str) -> list[str]:
    """The command lines a manual shows: inline code spans and fenced lines starting ``metadagger ``."""
    fenced = [line.strip() for block in FENCE.findall(text) for line in block.splitlines()]
    spans = INLINE.findall(FENCE.sub("", text))
    return [line.split("#")[0].strip() for line in [*spans, *fenced] if line.startswith("metadagger ")]


def _options(command: Any) -> set[str]:
    return {"--help", *(opt for param in command.params for opt in (*param.opts, *param.secondary_opts))}


def _problems(line: str) -> list[str]:
    """What in one shown command line the command line does not have: commands (each alternative of
    ``a|b``) and ``--options`` of the command they reach."""
    words, commands = line.split()[1:], [COMMAND_LINE]
    while words and all(hasattr(c, "commands") for c in commands) and not words[0].startswith("-"):
        names = words.pop(0).split("|")
        missing = [n for n in names for c in commands if n not in c.commands]
        if missing:
            return [f"no command {' or '.join(missing)}"]
        commands = [c.commands[n] for c in commands for n in names]
    flags = {w.strip("[](),.;:").split("=")[0] for w in words}
    return [
        f"{c.name} takes no {flag}"
        for c in commands
        for flag in sorted(f for f in flags if f.startswith("--"))
        if flag not in _options(c)
    ]


@pytest.mark.parametrize("manual", MANUALS, ids=lambda p: p.name)
def test_every_command_line_a_manual_shows_exists(manual):
    shown = _mentions(manual.read_text())
    problems = [f"`{line}`: {problem}" for line in shown for problem in _problems(line)]
    assert not problems, f"{manual.name} shows what the command line does not have:\n" + "\n".join(problems)


def test_the_readmes_command_line_block_names_every_command():
    text = (ROOT / "README.md").read_text()
    block = text.split("## Command line", 1)[1]
    listing = block[: block.index("```", block.index("```") + 3) + 3]  # the section's first fenced block
    named: dict[str, set[str]] = {}
    for line in _mentions(listing):
        first, *rest = line.split()[1:]
        for name in first.split("|"):
            group = COMMAND_LINE.commands.get(name)
            subs = rest[0].split("|") if hasattr(group, "commands") and rest else []
            named.setdefault(name, set()).update(subs)
    unnamed = sorted(set(COMMAND_LINE.commands) - set(named))
    unnamed += sorted(
        f"{name} {sub}"
        for name, command in COMMAND_LINE.commands.items()
        if hasattr(command, "commands")
        for sub in command.commands
        if sub not in named.get(name, set())
    )
    assert not unnamed, f"README.md's Command line block leaves out: {', '.join(unnamed)}"


def test_a_wrong_command_or_option_is_caught():
    assert _problems("metadagger reproduce --task carracing --preset quick --out RUN") == []
    assert _problems("metadagger results add|build --out RUN") == ["build takes no --out"]
    assert _problems("metadagger results publish") == ["no command publish"]
    assert _problems("metadagger bench lanes --out RUN [--widths 8]") == ["lanes takes no --widths"]


def _sections(manual: Path) -> set[str]:
    """A manual's headings and bold paragraph labels (``**Equal budgets** ...``), in lower case."""
    text = manual.read_text()
    names = re.findall(r"^#+\s+(.*)$", text, re.M) + re.findall(r"^\*\*([^*]+?)\.?\*\*", text, re.M)
    return {" ".join(name.split()).lower() for name in names}


def _pointer_problems(text: str) -> list[str]:
    sections = {manual.name: _sections(manual) for manual in MANUALS}
    problems = []
    for match in POINTER.finditer(text):
        manual, name = match[1], " ".join((match[2] or match[3]).split())
        if manual in sections and not any(s.startswith(name.lower()) for s in sections[manual]):
            problems.append(f'{manual}, "{name}"')
    return problems


def test_every_pointer_to_a_manuals_section_names_one():
    problems = [
        f"{path.relative_to(ROOT)}: {problem}"
        for path in POINTING
        if path.is_file()
        for problem in _pointer_problems(path.read_text(errors="replace"))
    ]
    assert not problems, "pointers to no section of their manual:\n" + "\n".join(problems)


def test_a_pointer_to_a_missing_section_is_caught():
    assert _pointer_problems("see docs/fetch.md, \"The pairs\" and ([benchmark](benchmark.md), 'Equal budgets')") == []
    assert _pointer_problems('(docs/fetch.md, "Pairs that vanished")') == ['fetch.md, "Pairs that vanished"']


def _commands(group: Any, prefix: str = "") -> dict[str, Any]:
    found = {}
    for name, command in group.commands.items():
        found[prefix + name] = command
        if hasattr(command, "commands"):
            found.update(_commands(command, f"{prefix}{name} "))
    return found


def test_every_command_opens_its_help_with_a_one_line_summary():
    broken = [
        name
        for name, command in _commands(COMMAND_LINE).items()
        if "\n" in inspect.cleandoc(command.help or "").split("\n\n")[0] or not command.help
    ]
    assert not broken, f"help without a one-line summary (then a blank line, then the details): {', '.join(broken)}"
