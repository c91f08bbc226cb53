"""The report section of the mapping diagnostics (``metadagger diagnose``), built from
``diagnostics/mapping.json`` alone."""

from __future__ import annotations

import math

from metadagger.evaluation.benchmark.labels import method_label, method_order
from metadagger.evaluation.diagnose import plot_scaling
from metadagger.evaluation.report.tables import figure_lines, markdown_table
from metadagger.mapping.registry import get_kind
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json

FIGURE = "diagnostics_scaling.png"


def _cell(stat: dict | None, digits: str = ".3g") -> str:
    return "-" if not stat else f"{stat['mean']:{digits}} ± {stat['sd']:{digits}}"


def _minus(stat: dict | None) -> str:
    if not stat or math.isnan(stat["low"]):
        return "-"
    return f"{stat['mean']:+.3f} ({stat['low']:+.3f} to {stat['high']:+.3f})"


def _times(value: float) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.2f}x"


def _scaling_cell(row: dict) -> str:
    difference = row.get("function_minus_bc")
    return f"{row['function']:.3g}" + ("" if not difference else f" [{_minus(difference)}]")


def _short(kind: str) -> str:
    return method_label(kind).removesuffix(" (control)")


def _nearer_than_controls(methods: dict[str, dict], controls: list[str]) -> str:
    """Which learned kinds are nearer to w_DA in actions than every control, paired over the
    validation pairs (every 95% interval of the difference below 0)."""
    if not controls:
        return "The run has no control to compare the mappers with."
    names = " and ".join(_short(c) for c in controls)
    nearer = [
        method_label(name)
        for name in method_order(methods)
        if name != "bc"
        and get_kind(name).learned
        and all((d := methods[name].get(f"function_minus_{c}")) and d["high"] < 0 for c in controls)
    ]
    if not nearer:
        return (
            f"No learned mapper is nearer to w_DA in actions than {names} on these validation pairs "
            "(no paired 95% interval lies below 0 against each)."
        )
    return (
        f"Nearer to w_DA in actions than {names} on these validation pairs (every paired 95% interval below 0): "
        f"{', '.join(nearer)}."
    )


def diagnostics_section(layout: RunLayout) -> list[str]:
    """Function- and weight-space errors beside the noise ceiling, memorisation, data scaling."""
    if not layout.diagnostics_summary.is_file():
        return []
    s = read_json(layout.diagnostics_summary, "the diagnostics summary")
    function = "action mismatch rate" if s["discrete"] else "mean squared action error"
    ceiling = s["noise_ceiling"]
    lines = [
        "## Does a mapper learn anything?",
        "",
        f"On the {s['val_pairs']} validation pairs (mappers trained on {s['train_pairs']}): the function-space error "
        "is the "
        f"{function} of the predicted head against the seed's w_DA on {s['states_per_seed']} of that seed's DAgger "
        "states; "
        "the weight-space error is the MSE of the heads"
        + (" after removing the softmax's free shift" if s["discrete"] else "")
        + ". The noise ceiling is the same distance between w_DA heads of one seed that differ only by their fits' "
        "seeds "
        f"({ceiling['heads_per_seed']} heads on each of {len(ceiling['seeds'])} validation seeds): no mapper can beat "
        "it. "
        "Memorisation: distance of a prediction to the nearest training w_DA over its distance to its own w_DA "
        "(near 0: it returns a training example). Mean ± sd over the validation pairs; minus w_BC's (or a "
        "control's): the function-space error less w_BC's (the control's) on the same pair, mean and 95% interval "
        "(below 0: the method's head is nearer to w_DA in actions).",
        "",
    ]
    controls = [name for name in method_order(s["methods"]) if name != "bc" and not get_kind(name).learned]
    references = ["bc", *controls]
    cells = [
        (
            "noise ceiling",
            _cell(ceiling["function"]),
            *("-" for _ in references),
            "1.00x",
            _cell(ceiling["weight"]),
            "1.00x",
            "-",
        )
    ]
    for name in method_order(s["methods"]):
        e = s["methods"][name]
        label = "BC (w_BC, no mapping)" if name == "bc" else method_label(name)
        cells.append(
            (
                label,
                _cell(e["function"]),
                *(_minus(e.get(f"function_minus_{r}")) for r in references),
                _times(e["function_over_ceiling"]),
                _cell(e["weight"]),
                _times(e["weight_over_ceiling"]),
                f"{e['memorisation_median']:.2f}",
            )
        )
    lines += markdown_table(
        (
            "method",
            "function-space error",
            "minus w_BC's (95%)",
            *(f"minus {_short(c)}'s (95%)" for c in controls),
            "x ceiling",
            "weight-space error",
            "x ceiling",
            "memorisation (median)",
        ),
        cells,
    )
    lines += ["", _nearer_than_controls(s["methods"], controls)]
    if s["scaling"]:
        lines += [
            "",
            "### Data scaling (validation function-space error, nested shares of the training pairs; "
            "in brackets, minus w_BC's with its 95% interval)",
            "",
        ]
        fractions = sorted({r["fraction"] for r in s["scaling"]})
        kinds = list(dict.fromkeys(r["kind"] for r in s["scaling"]))
        by = {(r["kind"], r["fraction"]): r for r in s["scaling"]}
        header = ("kind", *(f"{f:.0%} ({by[(kinds[0], f)]['train_pairs']} pairs)" for f in fractions))
        lines += markdown_table(
            header, [(method_label(k), *(_scaling_cell(by[(k, f)]) for f in fractions)) for k in kinds]
        )
        lines += [""] + figure_lines(
            layout.figures, FIGURE, "data scaling", lambda path: plot_scaling(s["scaling"], s["methods"], path)
        )
    return lines + [""]
