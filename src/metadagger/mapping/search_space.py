"""The mapper hyperparameter search's space: which :class:`~metadagger.mapping.config.MapperConfig`
fields a study of a kind samples, and how a trial's params become a config (``metadagger tune``,
:mod:`metadagger.mapping.tune`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from metadagger.errors import UserError
from metadagger.mapping.config import MapperConfig
from metadagger.mapping.registry import get_kind, kind_names, trained_names
from metadagger.utils.yaml_config import build, to_dict

__all__ = [
    "baseline_params",
    "check_tunable",
    "config_overrides",
    "import_optuna",
    "param_field",
    "search_space",
    "trial_config",
]

_INSTALL_OPTUNA = 'pip install -c constraints.txt -e ".[tune]"'
_WIDTHS = (64, 128, 256, 512)
_LATENTS = (16, 32, 64, 128)
# tuple fields of MapperConfig, searched as a depth and one width per layer: Optuna's categorical
# choices cannot be tuples, and equal widths keep the space small
_SHAPES = {"hidden": ("hidden_depth", "hidden_width"), "ae_hidden": ("ae_depth", "ae_width")}


def check_tunable(kind: str) -> None:
    """Raise a one-line :class:`UserError` unless ``kind`` is trained by Adam (has hyperparameters)."""
    if kind in trained_names():
        return
    if kind not in kind_names():
        why = "is not a mapper kind"
    elif get_kind(kind).learned:
        why = "is fitted in closed form (its λ is cross-validated), so it has no hyperparameters to tune"
    else:
        why = "is a control (a constant head), so it has no hyperparameters to tune"
    raise UserError(
        f"--kind {kind!r} {why}; tune one of {', '.join(trained_names())}, e.g. `metadagger tune --out RUN --kind sam`"
    )


def search_space(kind: str, base: MapperConfig) -> dict[str, Any]:
    """The Optuna distributions a new study of ``kind`` samples, by parameter name.

    Every kind: the mapping MLP's (DM's network, or h) depth, width, dropout and weight decay,
    the learning rate and BatchNorm of every network, and the epochs. Kinds with autoencoders add
    their latent width, depth, width, dropout, weight decay and epochs. Epochs range from a quarter
    of ``base``'s to twice them (log scale), so the run's ``mappers.<kind>`` settings bound a
    trial's cost; ``base``'s widths join the width choices so trial 0 can be ``base`` itself.
    """
    check_tunable(kind)
    distributions = import_optuna().distributions
    floats, ints, choices = (
        distributions.FloatDistribution,
        distributions.IntDistribution,
        distributions.CategoricalDistribution,
    )
    space = {
        "lr": floats(1e-5, 1e-2, log=True),
        "weight_decay": floats(1e-7, 1e-2, log=True),
        "hidden_depth": ints(1, 3),
        "hidden_width": choices(sorted({*_WIDTHS, *base.hidden})),
        "dropout": floats(0.0, 0.5),
        "batchnorm": choices((True, False)),
        "epochs": _epochs(ints, base.epochs),
    }
    if get_kind(kind).route.encoder is not None:
        space |= {
            "latent": choices(sorted({*_LATENTS, base.latent})),
            "ae_depth": ints(1, 2),
            "ae_width": choices(sorted({*_WIDTHS, *base.ae_hidden})),
            "ae_dropout": floats(0.0, 0.3),
            "ae_weight_decay": floats(1e-8, 1e-3, log=True),
            "ae_epochs": _epochs(ints, base.ae_epochs),
        }
    return space


def _epochs(ints: Any, epochs: int) -> Any:
    return ints(max(1, epochs // 4), 2 * epochs, log=True)


def config_overrides(params: Mapping[str, Any]) -> dict[str, Any]:
    """A trial's params as ``MapperConfig`` fields (plain YAML data: widths as lists)."""
    parts = {name for pair in _SHAPES.values() for name in pair}
    fields = {name: value for name, value in params.items() if name not in parts}
    for field, (depth, width) in _SHAPES.items():
        if depth in params:
            fields[field] = [params[width]] * params[depth]
    return fields


def trial_config(base: MapperConfig, params: Mapping[str, Any]) -> MapperConfig:
    """``base`` with a trial's params applied."""
    return build(MapperConfig, {**to_dict(base), **config_overrides(params)}, where=f"a {base.kind} trial")


def param_field(param: str) -> str:
    """The MapperConfig field a param sets."""
    return next((field for field, pair in _SHAPES.items() if param in pair), param)


def baseline_params(base: MapperConfig, space: Mapping[str, Any]) -> dict[str, Any] | None:
    """``base`` as params of ``space``; None where the space cannot express it (unequal widths, a
    value outside a range)."""
    params = {}
    for name in space:
        field = param_field(name)
        value = getattr(base, field)
        if field in _SHAPES:
            if len(set(value)) != 1:
                return None
            value = len(value) if name == _SHAPES[field][0] else value[0]
        params[name] = value
    return params if all(_contains(space[name], value) for name, value in params.items()) else None


def _contains(distribution: Any, value: Any) -> bool:
    choices = getattr(distribution, "choices", None)
    return value in choices if choices is not None else distribution.low <= value <= distribution.high


def import_optuna() -> Any:
    """The optuna module, or a one-line :class:`UserError` saying how to install it."""
    try:
        import optuna
    except ImportError:
        raise UserError(
            f"metadagger tune needs Optuna, which is not installed; install it with: {_INSTALL_OPTUNA}"
        ) from None
    return optuna
