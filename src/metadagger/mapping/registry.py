"""The mapper kinds: each declared once, here, and read by training, evaluation, reports and the CLI.

A kind is either *learned* (networks fitted on the training pairs, by Adam or in closed form,
reached through a :class:`Route`) or a *control* (a constant head that ignores w_BC, computed from the training
pairs or pi*). Adding a kind takes a module with its builder (see :mod:`metadagger.mapping.networks`)
and one :func:`register_kind` line; docs/mapping.md shows an example. An installed package adds
one with an entry point in the group ``metadagger.mappers`` naming its :class:`MapperKind`
(``mykind = "mypkg.mapper:KIND"``), loaded on first use; a broken one is one
:class:`~metadagger.errors.UserError` naming its package.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch
from torch import nn

from metadagger.errors import UserError
from metadagger.mapping import modes, networks, ridge
from metadagger.utils.plugins import load_plugins


class Route(NamedTuple):
    """How a learned kind maps: standardise, encode, core network, decode, unstandardise.

    Scaler names: ``bc`` (fitted on w_BC), ``da`` (on w_DA) or ``all`` (on both).
    """

    in_scaler: str
    encoder: str | None
    core: str
    decoder: str | None
    out_scaler: str


Builder = Callable[..., dict[str, nn.Module]]
"""``builder(dim, **architecture fields, generator=...) -> {network name: module}``."""
Constant = Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor]
"""``constant(w_da_train [N, d], pistar_head [d] or None) -> head [d]`` of a control."""
ClosedForm = Callable[[nn.Module, torch.Tensor, torch.Tensor], dict]
"""``closed_form(core, x_train, y_train) -> what it chose``: sets the route's core network in place
from the standardised training rows, instead of Adam epochs."""


@dataclass(frozen=True)
class MapperKind:
    """One mapper kind: its name, how reports label it, and how it is built."""

    name: str
    """The kind's name in configs, on the command line and in folder names."""
    label: str
    """How tables and figures name it."""
    summary: str
    """One line for help texts and docs."""
    route: Route | None = None
    """Learned kinds: how a head flows through the networks."""
    build: Builder | None = None
    """Learned kinds: the untrained networks."""
    constant: Constant | None = None
    """Controls: the head they always return."""
    paper_epochs: int | None = None
    """Training epochs of the paper's Table 8 (learned kinds)."""
    closed_form: ClosedForm | None = None
    """Learned kinds fitted in closed form (no autoencoder): how the core is set."""
    context: bool = False
    """Learned kinds that also read the seed's context (:func:`metadagger.metal_dagger.method.seed_context`): the core
    receives the standardised w_BC followed by the standardised context (scaler ``context``)."""

    def __post_init__(self) -> None:
        if (self.route is None) != (self.build is None) or (self.build is None) == (self.constant is None):
            raise ValueError(f"mapper kind {self.name!r} needs either route and build (learned) or constant (control)")
        if self.closed_form is not None and (self.route is None or self.route.encoder or self.route.decoder):
            raise ValueError(f"mapper kind {self.name!r}: a closed-form fit needs a route without autoencoders")
        if self.context and (self.route is None or self.route.encoder or self.route.decoder):
            raise ValueError(f"mapper kind {self.name!r}: a context needs a route without autoencoders")

    @property
    def learned(self) -> bool:
        """Whether the kind fits networks on the training pairs."""
        return self.build is not None

    @property
    def network_names(self) -> tuple[str, ...]:
        """The names of the kind's networks (none for a control)."""
        if self.route is None:
            return ()
        return tuple(dict.fromkeys(n for n in (self.route.encoder, self.route.core, self.route.decoder) if n))

    @property
    def scaler_names(self) -> tuple[str, ...]:
        """The names of the kind's standardisers (none for a control)."""
        if self.route is None:
            return ()
        return tuple(
            dict.fromkeys((self.route.in_scaler, self.route.out_scaler) + (("context",) if self.context else ()))
        )


#: Entry-point group through which installed packages add mapper kinds.
ENTRY_POINT_GROUP = "metadagger.mappers"
_KINDS: dict[str, MapperKind] = {}
_plugins_loaded = False


def register_kind(kind: MapperKind) -> MapperKind:
    """Make ``kind`` known everywhere (training, evaluation, reports, the CLI); returns it."""
    _KINDS[kind.name] = kind
    return kind


def _kinds() -> dict[str, MapperKind]:
    """Every kind: the built-in and registered ones, then those of installed packages (loaded once)."""
    global _plugins_loaded
    if not _plugins_loaded:
        for kind in load_plugins(
            ENTRY_POINT_GROUP, plugin="mapper", thing="mapper kind", expected=MapperKind, known=_KINDS
        ):
            register_kind(kind)
        _plugins_loaded = True  # only once every one loaded: a broken one is named by every later call
    return _KINDS


def get_kind(name: str) -> MapperKind:
    """The kind called ``name``; an unknown name is a :class:`UserError` listing the known ones."""
    kinds = _kinds()
    if name not in kinds:
        raise UserError(f"unknown mapper kind {name!r}: expected one of {', '.join(kinds)}")
    return kinds[name]


def kind_names() -> tuple[str, ...]:
    """Every kind, learned ones first, in registration order."""
    return learned_names() + control_names()


def learned_names() -> tuple[str, ...]:
    """The learned kinds."""
    return tuple(k.name for k in _kinds().values() if k.learned)


def trained_names() -> tuple[str, ...]:
    """The learned kinds trained by Adam (not fitted in closed form): those with hyperparameters
    to tune (:mod:`metadagger.mapping.tune`)."""
    return tuple(k.name for k in _kinds().values() if k.learned and k.closed_form is None)


def control_names() -> tuple[str, ...]:
    """The controls."""
    return tuple(k.name for k in _kinds().values() if not k.learned)


def context_inputs(kind: str, early_stop: float | None) -> dict[str, float | None]:
    """What a row made with ``kind`` depends on beyond its mapper file: for a kind with a context,
    the early stop that cut the BC rollout the context summarises; nothing for the others."""
    return {"context_early_stop": early_stop} if get_kind(kind).context else {}


def _mean_da(w_da_train: torch.Tensor, pistar_head: torch.Tensor | None) -> torch.Tensor:
    if w_da_train.ndim != 2 or w_da_train.shape[0] == 0:
        raise UserError(f"mean-da needs training rows [N, d] with N >= 1, got shape {tuple(w_da_train.shape)}")
    return w_da_train.mean(dim=0)


def _pistar_head(w_da_train: torch.Tensor, pistar_head: torch.Tensor | None) -> torch.Tensor:
    if pistar_head is None:
        raise UserError("the pistar-head control needs pistar_head=pi*'s head vector (policy.head_vector())")
    if pistar_head.ndim != 1 or pistar_head.numel() == 0:
        raise UserError(
            f"pistar_head must be a non-empty 1-D head vector, got shape {tuple(pistar_head.shape)}; pass pi*'s "
            "policy.head_vector()"
        )
    return pistar_head.clone()


register_kind(
    MapperKind(
        "dm",
        "DM",
        "direct mapping: one MLP from w_BC to w_DA (3.3.1)",
        route=Route("bc", None, "dm", None, "da"),
        build=networks.build_dm,
        paper_epochs=500,
    )
)
register_kind(
    MapperKind(
        "sam",
        "SAM",
        "single autoencoder of w_BC and w_DA, h between its codes (3.3.2)",
        route=Route("all", "sigma_all", "h", "sigma_all", "all"),
        build=networks.build_sam,
        paper_epochs=1000,
    )
)
register_kind(
    MapperKind(
        "tam",
        "TAM",
        "twin autoencoders of w_BC and of w_DA, h between their codes (3.3.2)",
        route=Route("bc", "sigma_bc", "h", "sigma_da", "da"),
        build=networks.build_tam,
        paper_epochs=1000,
    )
)
register_kind(
    MapperKind(
        "ridge",
        "Ridge",
        "ridge regression of the update w_DA - w_BC on w_BC, λ by cross-validation",
        route=Route("all", None, "ridge", None, "all"),
        build=ridge.build_ridge,
        closed_form=ridge.fit_ridge,
    )
)
register_kind(
    MapperKind(
        "modes",
        "Modes",
        "the mean w_DA of the training pairs' group (k-means) that a ridge classifier of w_BC picks; K and λ by "
        "cross-validation",
        route=Route("bc", None, "modes", None, "da"),
        build=modes.build_modes,
        closed_form=modes.fit_modes,
    )
)
register_kind(
    MapperKind(
        "conditioned",
        "Conditioned",
        "ridge regression of the update on w_BC and the seed's context "
        "(demonstration and BC-rollout features; no further expert label), λ and the context's weight by "
        "cross-validation",
        route=Route("all", None, "ridge", None, "all"),
        build=ridge.build_ridge,
        closed_form=ridge.fit_ridge,
        context=True,
    )
)
register_kind(
    MapperKind("mean-da", "mean-DA (control)", "control: always the training pairs' mean w_DA", constant=_mean_da)
)
register_kind(MapperKind("pistar-head", "pi*-head (control)", "control: always pi*'s own head", constant=_pistar_head))
