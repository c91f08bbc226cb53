"""The report section of the mapping diagnostics (``metadagger diagnose``), built from
``diagnostics/mapping.json`` alone."""

from __future__ import annotations

import math

from metadagger.evaluation.diagnose import plot_scaling
from metadagger.evaluation.tables import figure_lines, markdown_table, method_label, method_order
from metadagger.runfolder.layout import RunLayout
from metadagger.utils.io import read_json

FIGURE = "diagnostics_scaling.png"


def _cell(stat: dict | None, digits: str = ".3g") -> str:
    return "-" if not stat else f"{stat['mean']:{digits}} ± {stat['sd']:{digits}}"


def _minus_bc(stat: dict | None) -> str:
    if not stat or math.isnan(stat["low"]):
        return "-"
    return f"{stat['mean']:+.3f} ({stat['low']:+.3f} to {stat['high']:+.3f})"


def _times(value: float) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.2f}x"


def _scaling_cell(row: dict) -> str:
    difference = row.get("function_minus_bc")
    return f"{row['function']:.3g}" + ("" if not difference else f" [{_minus_bc(difference)}]")


def diagnostics_section(layout: RunLayout) -> list[str]:
    """Function- and weight-space errors beside the noise ceiling, memorisation, data scaling."""
    if not layout.diagnostics_summary.is_file():
        return []
    s = read_json(layout.diagnostics_summary, "the diagnostics summary")
    function = "action mismatch rate" if s["discrete"] else "mean squared action error"
    ceiling = s["noise_ceiling"]
    lines = ["## Does a mapper learn anything?", "",
             f"On the {s['val_pairs']} validation pairs (mappers trained on {s['train_pairs']}): the function-space error is the "
             f"{function} of the predicted head against the seed's w_DA on {s['states_per_seed']} of that seed's DAgger states; "
             "the weight-space error is the MSE of the heads" + (" after removing the softmax's free shift" if s["discrete"] else "")
             + ". The noise ceiling is the same distance between w_DA heads of one seed that differ only by their fits' seeds "
             f"({ceiling['heads_per_seed']} heads on each of {len(ceiling['seeds'])} validation seeds): no mapper can beat it. "
             "Memorisation: distance of a prediction to the nearest training w_DA over its distance to its own w_DA "
             "(near 0: it returns a training example). Mean ± sd over the validation pairs; minus w_BC's: the "
             "function-space error less w_BC's on the same pair, mean and 95% interval (below 0: the mapping brings "
             "the head nearer to w_DA in actions).", ""]
    cells = [("noise ceiling", _cell(ceiling["function"]), "-", "1.00x", _cell(ceiling["weight"]), "1.00x", "-")]
    for name in method_order(s["methods"]):
        e = s["methods"][name]
        label = "BC (w_BC, no mapping)" if name == "bc" else method_label(name)
        cells.append((label, _cell(e["function"]), _minus_bc(e.get("function_minus_bc")), _times(e["function_over_ceiling"]),
                      _cell(e["weight"]), _times(e["weight_over_ceiling"]), f"{e['memorisation_median']:.2f}"))
    lines += markdown_table(("method", "function-space error", "minus w_BC's (95%)", "x ceiling", "weight-space error",
                             "x ceiling", "memorisation (median)"), cells)
    if s["scaling"]:
        lines += ["", "### Data scaling (validation function-space error, nested shares of the training pairs; "
                  "in brackets, minus w_BC's with its 95% interval)", ""]
        fractions = sorted({r["fraction"] for r in s["scaling"]})
        kinds = list(dict.fromkeys(r["kind"] for r in s["scaling"]))
        by = {(r["kind"], r["fraction"]): r for r in s["scaling"]}
        header = ("kind", *(f"{f:.0%} ({by[(kinds[0], f)]['train_pairs']} pairs)" for f in fractions))
        lines += markdown_table(header, [(method_label(k), *(_scaling_cell(by[(k, f)]) for f in fractions)) for k in kinds])
        lines += [""] + figure_lines(layout.figures, FIGURE, "data scaling", lambda path: plot_scaling(s["scaling"], s["methods"], path))
    return lines + [""]
