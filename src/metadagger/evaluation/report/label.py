"""The labelling sessions' section of a report: success against queries and against the seconds a person spent.

One table per session of ``metadagger label`` (``RUN/label/<expert>/<method>@<setting>/<seed>/``),
one line per finished round: the learner's outcome after the round's refit, the queries so far
(the demonstration's included), the takeovers, the labels given and the seconds they took, and who
gave them (a person, or the scripted expert). Built from each session's ``rows.jsonl`` and
``labels.jsonl`` alone.
"""

from __future__ import annotations

from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.ledger import effort
from metadagger.evaluation.report.tables import markdown_table
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.jsonl import read_lines


def label_section(layout: RunLayout) -> list[str]:
    """A table per labelling session with a finished round; [] for a run without one."""
    parts: list[str] = []
    for session in layout.label_sessions():
        rows = read_lines(session.rows, called="labelling session row")
        if not rows:
            continue
        labels = read_lines(session.labels, called="label record")
        first = rows[0]
        by = effort(labels, rows[-1]["round"])["labelled_by"]
        parts += [
            f"### {method_label(first['method'])} {first['setting']}, seed {first['seed']}, labelled by {by}",
            "",
            f"`{session.root.relative_to(layout.root)}`: the learner after each round, against the queries "
            "(the demonstration's included) and the seconds the labels of rounds 1 to that one took.",
            "",
        ]
        table = []
        for row in rows:
            spent = effort(labels, row["round"])
            outcome = "success" if row["success"] else "failure"
            table.append(
                (
                    row["round"],
                    f"{outcome} ({row['steps']} steps)",
                    row["expert_queries"],
                    row["takeovers"],
                    spent["labels"],
                    f"{spent['seconds']:.1f}",
                    spent["switches"],
                    spent["labelled_by"],
                )
            )
        header = ("round", "learner", "queries", "takeovers", "labels", "seconds", "switches", "labelled by")
        parts += [*markdown_table(header, table), ""]
    if not parts:
        return []
    intro = [
        "## A person as the expert",
        "",
        "Gated DAgger on one seed with its labels given at `metadagger label`'s page (docs/label.md): *labels* and "
        "*seconds* count the labels of rounds 1 to that round and the time from each state's showing to its answer; "
        "*switches*, the takeovers begun (the person's attention moved to the learner's episode); *labelled by* "
        "says who answered: a person, or the scripted expert.",
        "",
    ]
    return intro + parts
