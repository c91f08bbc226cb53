"""``metadagger diagnose``: does a mapper learn anything, or memorise, or sit at the noise floor?

Per validation pair (docs/diagnostics.md, "What is measured"), with the yardsticks of
:mod:`metadagger.mapping.diagnostics`:

- **state samples**: the seed's pair procedure is re-run (it is deterministic; the run checks
  that it gives the stored w_BC and w_DA) and a fixed-size, evenly spaced sample of the trunk
  features of its DAgger states is kept in ``diagnostics/states/<seed>.safetensors`` (beside the
  pair, so runs collected before the diagnostics existed need no new pairs);
- **noise ceiling**: on the first ``noise_seeds`` validation seeds, the same procedure with
  ``noise_refits`` other fit seeds (same demonstration, expert and env seeds); the mean pairwise
  distance of those w_DA is the error no mapper can beat;
- for every kind and control of the run (and ``bc``: w_BC left as it is): weight-space error
  (canonical for discrete heads, and raw), function-space error, memorisation, each error also as
  a multiple of the noise ceiling;
- **data scaling**: each learned kind retrained on nested shares of the training pairs (one
  seed-fixed order), its function-space error on the same validation pairs.

The per-seed work runs on the one driver (resumable, parallel); the mappers of the scaling curve
resume like any mapper. Results: ``diagnostics/mapping.json`` and ``diagnostics/scaling.png``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.imitation.metrics import mean_interval
from metadagger.mapping.config import MapperConfig
from metadagger.mapping.diagnostics import canonical_heads, function_error, memorisation, pairwise_spread, weight_error
from metadagger.mapping.mappers import Mapper
from metadagger.mapping.registry import get_kind
from metadagger.mapping.train import MapperJob, mapper_stamp, train_mappers
from metadagger.metal_dagger.lane_blocks import in_blocks
from metadagger.metal_dagger.pairs import PairConfig, pair_stamp, run_pair
from metadagger.metal_dagger.store import PairSplit
from metadagger.runfolder.driver import RowLog, SeedJob, StageOptions, drive, plan
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks.base import Task
from metadagger.utils.io import load_tensors, save_tensors, write_json
from metadagger.utils.plotting import draw_figure, plt, save_figure

#: Line styles of the constant controls in the scaling figure (one each, in turn).
CONTROL_DASHES = ("-.", ":", (0, (5, 2, 1, 2, 1, 2)))

#: Fit seed of the m-th refit of a noise-ceiling seed: ``seed + REFIT_STRIDE * m``.
REFIT_STRIDE = 1_000_003


@dataclass(frozen=True)
class DiagnoseConfig:
    """How much the mapping diagnostics measure."""

    states: int = 256
    """DAgger states (their trunk features) kept per validation seed for function-space errors."""
    noise_seeds: int = 10
    """Validation seeds whose DAgger is re-run with other fit seeds (the noise ceiling)."""
    noise_refits: int = 2
    """Other fit seeds per noise-ceiling seed (with the pair's own: noise_refits + 1 heads)."""
    scaling: tuple[float, ...] = (0.25, 0.5, 1.0)
    """Shares of the training pairs each learned kind is retrained on (nested subsets)."""

    def __post_init__(self) -> None:
        if not isinstance(self.states, int) or self.states < 1:
            raise UserError(f"diagnose.states must be an integer >= 1, got {self.states!r}")
        if not isinstance(self.noise_seeds, int) or self.noise_seeds < 0:
            raise UserError(f"diagnose.noise_seeds must be an integer >= 0, got {self.noise_seeds!r}")
        if not isinstance(self.noise_refits, int) or self.noise_refits < 1:
            raise UserError(f"diagnose.noise_refits must be an integer >= 1, got {self.noise_refits!r}")
        if not self.scaling or not all(0.0 < f <= 1.0 for f in self.scaling):
            raise UserError(
                f"diagnose.scaling must be shares in (0, 1], got {list(self.scaling)!r}; e.g. [0.25, 0.5, 1.0]"
            )


@dataclass(frozen=True)
class DiagnoseJob(SeedJob):
    """One validation seed's diagnostics work: methods ``states`` and/or ``noise``."""

    pairs: PairConfig
    config: DiagnoseConfig


def diagnose_seed(job: DiagnoseJob) -> dict[str, Any]:
    """Re-run the seed's pair (and, for ``noise``, its refits); returns rows and tensors."""
    out: dict[str, Any] = {"seed": job.seed, "entries": {}, "tensors": {}}
    if "states" in job.methods:
        pair = run_pair(job.task, job.pistar, job.seed, job.pairs, with_states=True)
        n = len(pair.dagger_features)
        keep = (
            np.unique(np.linspace(0, n - 1, min(job.config.states, n)).round().astype(int))
            if n
            else np.zeros(0, dtype=int)
        )
        out["tensors"]["states"] = {
            "features": pair.dagger_features[torch.from_numpy(keep)].contiguous(),
            "w_bc": torch.from_numpy(pair.w_bc),
            "w_da": torch.from_numpy(pair.w_da),
        }
        out["entries"]["states"] = [{"seed": job.seed, "states": int(len(keep)), "dagger_states": int(n)}]
    if "noise" in job.methods:
        refits = [
            run_pair(job.task, job.pistar, job.seed, job.pairs, fit_seed=job.seed + REFIT_STRIDE * m).w_da
            for m in range(1, job.config.noise_refits + 1)
        ]
        out["tensors"]["noise"] = {"w_da": torch.from_numpy(np.stack(refits))}
        out["entries"]["noise"] = [{"seed": job.seed, "refits": len(refits)}]
    return out


def collect_seed_data(
    task: Task, layout: RunLayout, pairs: PairConfig, config: DiagnoseConfig, split: PairSplit, options: StageOptions
) -> None:
    """Run the missing per-seed work: state samples of every validation seed, refits of the
    noise-ceiling seeds; each result is checked against the stored pair and saved."""
    base = pair_stamp(task, layout, pairs)
    stamps = {"states": {**base, "states": config.states}, "noise": {**base, "refits": config.noise_refits}}
    log = RowLog(layout.diagnostics_log)
    noise = set(split.val_seeds[: config.noise_seeds])
    todo = plan(split.val_seeds, stamps, log, rebuild=True, called="the diagnostics", fix="")
    jobs = [
        DiagnoseJob(
            task=task,
            pistar=str(layout.pistar),
            seed=p.seed,
            pairs=pairs,
            config=config,
            methods=tuple(m for m in p.methods if m == "states" or p.seed in noise),
        )
        for p in todo
    ]
    stored = {seed: i for i, seed in enumerate(split.val_seeds)}
    # pairs made in lanes are made again in lanes of the same width: a pair depends on the width only
    work, units = in_blocks(diagnose_seed, [j for j in jobs if j.methods], pairs.lanes, options.workers)

    def save(result: dict[str, Any]) -> None:
        seed = result["seed"]
        states = result["tensors"].get("states")
        if states is not None:
            i = stored[seed]
            same = torch.equal(states["w_bc"], split.w_bc_val[i]) and torch.equal(states["w_da"], split.w_da_val[i])
            if not same:
                raise UserError(
                    f"re-running the pair of seed {seed} did not give its stored w_BC and w_DA: the pairs were made "
                    f"with other code or settings; run `metadagger pairs --out {layout.root} --rebuild`"
                )
            result["entries"]["states"][0]["reproduced"] = True
        for what, tensors in result.pop("tensors").items():
            save_tensors(layout.diagnostics_seed(what, seed), tensors, metadata={"seed": str(seed)})

    drive(
        work,
        units,
        log=log,
        stamps=stamps,
        save=save,
        options=options,
        desc="diagnostics",
    )


def _features(layout: RunLayout, seed: int) -> torch.Tensor:
    return load_tensors(layout.diagnostics_seed("states", seed), called=f"state sample of seed {seed}")["features"]


def _function_errors(
    predicted: torch.Tensor, split: PairSplit, features: list[torch.Tensor], *, outputs: int, discrete: bool
) -> torch.Tensor:
    """Function-space error of each validation pair's predicted head against its w_DA."""
    return torch.tensor(
        [
            function_error(p, t, f, outputs=outputs, discrete=discrete)
            for p, t, f in zip(predicted, split.w_da_val, features)
        ],
        dtype=torch.float64,
    )


def _errors(
    predicted: torch.Tensor,
    functions: torch.Tensor,
    split: PairSplit,
    *,
    outputs: int,
    discrete: bool,
    against: dict[str, torch.Tensor] | None = None,
) -> dict[str, Any]:
    """Weight- and function-space errors and memorisation of ``predicted``, whose per-pair
    function-space errors are ``functions``; for each ``name -> per-pair function-space error`` of
    ``against`` (w_BC's as ``bc``, a control's by its kind) also the paired difference to it with
    its 95% interval, as ``function_minus_<name>``."""
    truth = split.w_da_val
    weights = weight_error(predicted, truth, outputs=outputs, discrete=discrete)
    raw = weight_error(predicted, truth, outputs=outputs, discrete=False)
    if discrete:  # distances between heads that choose the same actions are 0
        ratios = memorisation(
            canonical_heads(predicted, outputs),
            canonical_heads(truth, outputs),
            canonical_heads(split.w_da_train, outputs),
        )
    else:
        ratios = memorisation(predicted, truth, split.w_da_train)
    errors = {
        "weight": _mean_sd(weights),
        "weight_raw": _mean_sd(raw),
        "function": _mean_sd(functions),
        "memorisation_median": float(ratios.median()),
        "memorisation_below_half": float((ratios < 0.5).to(torch.float64).mean()),
    }
    for name, reference in (against or {}).items():
        errors[f"function_minus_{name}"] = mean_interval((functions - reference).tolist())
    return errors


def _mean_sd(values: torch.Tensor) -> dict[str, float]:
    values = values.to(torch.float64)
    return {"mean": float(values.mean()), "sd": float(values.std(unbiased=False)), "n": int(len(values))}


def noise_ceiling(
    layout: RunLayout, split: PairSplit, config: DiagnoseConfig, *, outputs: int, discrete: bool
) -> dict[str, Any]:
    """Mean pairwise weight- and function-space distance of each noise seed's w_DA (its own and
    its refits'), averaged over the noise seeds."""
    seeds = split.val_seeds[: config.noise_seeds]
    weights, functions = [], []
    for seed in seeds:
        refits = load_tensors(layout.diagnostics_seed("noise", seed), called=f"refits of seed {seed}")["w_da"]
        heads = torch.cat([split.w_da_val[split.val_seeds.index(seed)][None], refits])
        weight, function = pairwise_spread(heads, _features(layout, seed), outputs=outputs, discrete=discrete)
        weights.append(weight)
        functions.append(function)
    return {
        "seeds": list(seeds),
        "heads_per_seed": config.noise_refits + 1,
        "weight": _mean_sd(torch.tensor(weights)) if seeds else None,
        "function": _mean_sd(torch.tensor(functions)) if seeds else None,
    }


def scaling_curve(
    layout: RunLayout,
    split: PairSplit,
    configs: dict[str, MapperConfig],
    fractions: tuple[float, ...],
    features: list[torch.Tensor],
    *,
    seed: int,
    outputs: int,
    discrete: bool,
    bc: torch.Tensor,
    trained: dict[str, Mapper] | None = None,
    options: StageOptions = StageOptions(),
) -> list[dict[str, Any]]:
    """Each learned kind of ``configs`` trained on nested shares of the training pairs (one order
    from ``seed``; the fits in parallel on ``options``' executor): its mean function- and
    weight-space error on the validation pairs, and its function-space error's paired difference
    to ``bc`` (w_BC's, per pair). A point made from the very pairs and config of a mapper in
    ``trained`` (the run's own, at 100%) takes that mapper instead of a new fit."""
    order = np.random.default_rng(seed).permutation(len(split.train_seeds))
    points = [
        (kind, fraction, max(2, int(round(fraction * len(order)))))
        for kind in configs
        for fraction in sorted(fractions)
    ]
    subsets = {count: split.with_train_rows(torch.from_numpy(np.sort(order[:count]))) for _, _, count in points}
    mappers: dict[int, Mapper] = {}
    jobs = {}
    for number, (kind, fraction, count) in enumerate(points):
        same = (trained or {}).get(kind)
        if same is not None and same.stamp == mapper_stamp(subsets[count], configs[kind]):
            mappers[number] = same
        else:
            jobs[number] = MapperJob(
                split=subsets[count],
                config=configs[kind],
                out_dir=layout.diagnostics_scaling(kind, fraction),
                name=f"{kind} on {count} pairs",
            )
    mappers.update(zip(jobs, train_mappers(list(jobs.values()), rebuild=True, options=options)))
    rows = []
    for number, (kind, fraction, count) in enumerate(points):
        heads = torch.from_numpy(mappers[number].map_batch(split.w_bc_val, split.context_val))
        functions = _function_errors(heads, split, features, outputs=outputs, discrete=discrete)
        errors = _errors(heads, functions, subsets[count], outputs=outputs, discrete=discrete, against={"bc": bc})
        rows.append(
            {
                "kind": kind,
                "fraction": fraction,
                "train_pairs": count,
                "function": errors["function"]["mean"],
                "weight": errors["weight"]["mean"],
                "function_minus_bc": errors["function_minus_bc"],
            }
        )
    return rows


def diagnose_mappers(
    task: Task,
    layout: RunLayout,
    split: PairSplit,
    mappers: dict[str, Mapper],
    pairs: PairConfig,
    config: DiagnoseConfig,
    *,
    scaling_configs: dict[str, MapperConfig],
    split_seed: int,
    outputs: int,
    discrete: bool,
    options: StageOptions = StageOptions(),
) -> dict[str, Any]:
    """Every diagnostic of every mapper in ``mappers`` on the validation pairs of ``split``; writes
    ``mapping.json`` and the scaling figure and returns the summary.

    Args:
        task, layout: the run's task and folder (pi* and the pairs are read from it).
        split: the run's current split of the kept pairs.
        mappers: kind -> the run's mapper of that kind (controls included).
        pairs: the pair settings (to re-run a pair exactly).
        config: sample sizes, noise seeds and scaling shares.
        scaling_configs: learned kind -> its training config, for the scaling curve.
        split_seed: orders the nested training subsets of the scaling curve.
        outputs, discrete: layer n's outputs and whether they are class logits.
        options: executor and progress of the per-seed work and of the scaling curve's fits.
    """
    if len(split.val_seeds) < 1:
        raise UserError("the diagnostics need validation pairs; raise pairs.val_fraction")
    collect_seed_data(task, layout, pairs, config, split, options)
    features = [_features(layout, seed) for seed in split.val_seeds]
    ceiling = noise_ceiling(layout, split, config, outputs=outputs, discrete=discrete)
    predicted = {"bc": split.w_bc_val} | {
        kind: torch.from_numpy(mapper.map_batch(split.w_bc_val, split.context_val)) for kind, mapper in mappers.items()
    }
    functions = {
        name: _function_errors(heads, split, features, outputs=outputs, discrete=discrete)
        for name, heads in predicted.items()
    }
    bc = functions["bc"]
    references = ["bc", *(kind for kind in mappers if not get_kind(kind).learned)]  # w_BC and the controls
    methods = {
        name: _errors(
            heads,
            functions[name],
            split,
            outputs=outputs,
            discrete=discrete,
            against={r: functions[r] for r in references if name != "bc" and r != name},
        )
        for name, heads in predicted.items()
    }
    for errors in methods.values():
        for space in ("weight", "function"):
            floor = ceiling[space]["mean"] if ceiling[space] else math.nan
            errors[f"{space}_over_ceiling"] = errors[space]["mean"] / floor if floor and floor > 0 else math.nan
    scaling = scaling_curve(
        layout,
        split,
        scaling_configs,
        config.scaling,
        features,
        seed=split_seed,
        outputs=outputs,
        discrete=discrete,
        bc=bc,
        trained=mappers,
        options=options,
    )
    summary = {
        "task": task.name,
        "discrete": discrete,
        "train_pairs": len(split.train_seeds),
        "val_pairs": len(split.val_seeds),
        "states_per_seed": config.states,
        "noise_ceiling": ceiling,
        "methods": methods,
        "scaling": scaling,
        "kinds": {kind: get_kind(kind).label for kind in mappers},
    }
    write_json(layout.diagnostics_summary, summary)
    draw_figure(layout.diagnostics_figure, lambda path: plot_scaling(scaling, methods, path))
    return summary


def plot_scaling(scaling: list[dict[str, Any]], methods: dict[str, Any], path: Path) -> Path:
    """Validation function-space error against training pairs (log scale, ticks at the curve's
    points), one line per learned kind; w_BC and the controls as horizontal lines, each its own dash."""
    fig, ax = plt.subplots(figsize=(8.0, 4.2), layout="constrained")
    for kind in dict.fromkeys(r["kind"] for r in scaling):
        rows = [r for r in scaling if r["kind"] == kind]
        ax.plot([r["train_pairs"] for r in rows], [r["function"] for r in rows], marker="o", label=get_kind(kind).label)
    dashes = itertools.cycle(CONTROL_DASHES)
    for name, errors in methods.items():
        if name == "bc":
            ax.axhline(errors["function"]["mean"], ls="--", lw=1, color="grey", label="BC (no mapping)")
        elif not get_kind(name).learned:
            ax.axhline(errors["function"]["mean"], ls=next(dashes), lw=1, color="black", label=get_kind(name).label)
    counts = sorted({r["train_pairs"] for r in scaling})
    ax.set_xscale("log")
    ax.set_xticks(counts, [str(c) for c in counts])
    ax.minorticks_off()
    ax.set_xlabel("training pairs")
    ax.set_ylabel("validation function-space error")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)
