"""Mappers f: w_BC -> estimate of w_DA on flat head vectors (paper section 3.3), saved and loaded.

Kinds:
    ``dm``: one MLP from standardised w_BC to standardised w_DA (3.3.1).
    ``sam``: one autoencoder sigma_ALL of w_BC and w_DA, f = D_ALL(h(E_ALL(w))) (3.3.2).
    ``tam``: autoencoders sigma_BC and sigma_DA, f = D_DA(h(E_BC(w))) (3.3.2).
    ``mean-da``: control, always the training set's mean w_DA.
    ``pistar-head``: control, always a given vector (pi*'s own head).

Every learned kind works in standardised space: a :class:`Standardizer` per data set, fitted on
the training split only and saved with the mapper. A mapper is one safetensors file whose
metadata holds kind, length and architecture, so :func:`load_mapper` rebuilds it without pickle.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from metadagger.errors import CheckpointError, UserError
from metadagger.io import load_tensors, read_metadata, save_tensors
from metadagger.mapping.autoencoder import Autoencoder
from metadagger.mapping.blocks import mlp
from metadagger.version import __version__

__all__ = [
    "ARCH_FIELDS",
    "CONTROL_KINDS",
    "KINDS",
    "LEARNED_KINDS",
    "ROUTES",
    "Mapper",
    "Route",
    "Standardizer",
    "build_networks",
    "load_mapper",
]

LEARNED_KINDS = ("dm", "sam", "tam")
CONTROL_KINDS = ("mean-da", "pistar-head")
KINDS = LEARNED_KINDS + CONTROL_KINDS
ARCH_FIELDS = ("hidden", "latent", "ae_hidden", "batchnorm", "dropout", "ae_dropout")
"""The config fields that decide the networks' shapes (stored with every mapper)."""

_FORMAT = "metadagger.mapper"
_FORMAT_VERSION = 1


class Route(NamedTuple):
    """How a learned kind maps: standardise, encode, core network, decode, unstandardise."""

    in_scaler: str
    encoder: str | None
    core: str
    decoder: str | None
    out_scaler: str


ROUTES = {
    "dm": Route(in_scaler="bc", encoder=None, core="dm", decoder=None, out_scaler="da"),
    "sam": Route(in_scaler="all", encoder="sigma_all", core="h", decoder="sigma_all", out_scaler="all"),
    "tam": Route(in_scaler="bc", encoder="sigma_bc", core="h", decoder="sigma_da", out_scaler="da"),
}


class Standardizer:
    """Per-dimension ``(x - mean) / std``, with std floored so near-constant entries stay finite.

    Args:
        mean: ``[d]`` float32.
        std: ``[d]`` float32, all > 0.
    """

    REL_FLOOR = 1e-3
    """A std below this share of the mean std is raised to it: a weight that barely varies in
    training must not turn a small deviation at inference into a huge standardised input."""

    def __init__(self, *, mean: torch.Tensor, std: torch.Tensor) -> None:
        if mean.ndim != 1 or mean.shape != std.shape:
            raise ValueError(f"mean and std must be 1-D of one length, got shapes {tuple(mean.shape)} and {tuple(std.shape)}")
        if not bool((std > 0).all()):
            raise ValueError("std must be > 0 everywhere")
        self.mean = mean.to(torch.float32)
        self.std = std.to(torch.float32)

    @classmethod
    def fit(cls, x: torch.Tensor) -> Standardizer:
        """Fit on rows ``x`` ``[N, d]`` (the training split only)."""
        mean = x.mean(dim=0)
        std = x.std(dim=0, unbiased=False)
        scale = float(std.mean())
        floor = cls.REL_FLOOR * scale if scale > 0 else 1.0  # all rows equal: leave units unchanged
        return cls(mean=mean, std=std.clamp_min(floor))

    def transform(self, x: torch.Tensor) -> torch.Tensor:
        """Standardise rows ``[N, d]``."""
        return (x - self.mean) / self.std

    def inverse(self, z: torch.Tensor) -> torch.Tensor:
        """Undo :meth:`transform`."""
        return z * self.std + self.mean


def build_networks(
    kind: str,
    dim: int,
    *,
    hidden: Sequence[int],
    latent: int,
    ae_hidden: Sequence[int],
    batchnorm: bool,
    dropout: float,
    ae_dropout: float,
    generator: torch.Generator | None = None,
) -> dict[str, nn.Module]:
    """The untrained networks of a kind, named as in :data:`ROUTES` (none for the controls).

    Autoencoders are built before h, so one generator gives the same weights every time.
    """
    if kind == "dm":
        return {"dm": mlp(dim, hidden, dim, batchnorm=batchnorm, dropout=dropout, generator=generator)}
    names = {"sam": ("sigma_all",), "tam": ("sigma_bc", "sigma_da")}.get(kind, ())
    nets: dict[str, nn.Module] = {
        name: Autoencoder(dim=dim, hidden=ae_hidden, latent=latent, batchnorm=batchnorm, dropout=ae_dropout, generator=generator)
        for name in names
    }
    if names:
        nets["h"] = mlp(latent, hidden, latent, batchnorm=batchnorm, dropout=dropout, generator=generator)
    return nets


class Mapper:
    """A trained mapping f: w_BC -> w_DA estimate, callable on flat float32 head vectors.

    Build one with :func:`metadagger.mapping.train.train_mapper`, :meth:`mean_da`,
    :meth:`pistar_head` or :func:`load_mapper`.

    Args:
        kind: one of :data:`KINDS`.
        dim: length of the head vectors.
        networks: the trained modules, named as in :data:`ROUTES` (learned kinds).
        scalers: the standardisers, named as in :data:`ROUTES` (learned kinds).
        constant: the vector a control always returns (controls).
        config: the training config as plain JSON data; its :data:`ARCH_FIELDS` rebuild the networks.
    """

    def __init__(
        self,
        *,
        kind: str,
        dim: int,
        networks: Mapping[str, nn.Module] | None = None,
        scalers: Mapping[str, Standardizer] | None = None,
        constant: torch.Tensor | None = None,
        config: Mapping[str, Any] | None = None,
    ) -> None:
        if kind not in KINDS:
            raise UserError(f"unknown mapper kind {kind!r}: expected one of {', '.join(KINDS)}")
        self.kind = kind
        self.dim = int(dim)
        self.networks = dict(networks or {})
        self.scalers = dict(scalers or {})
        self.constant = constant
        self.config = dict(config or {})
        if kind in CONTROL_KINDS:
            if constant is None or tuple(constant.shape) != (self.dim,) or constant.dtype != torch.float32:
                got = None if constant is None else f"{constant.dtype} {tuple(constant.shape)}"
                raise ValueError(f"a {kind} mapper needs a float32 constant of shape ({self.dim},), got {got}")
        else:
            route = ROUTES[kind]
            want_nets = {route.core, *(n for n in (route.encoder, route.decoder) if n)}
            want_scalers = {route.in_scaler, route.out_scaler}
            if set(self.networks) != want_nets or set(self.scalers) != want_scalers:
                raise ValueError(
                    f"a {kind} mapper needs networks {sorted(want_nets)} and scalers {sorted(want_scalers)}, "
                    f"got {sorted(self.networks)} and {sorted(self.scalers)}"
                )

    @classmethod
    def mean_da(cls, w_da_train: np.ndarray | torch.Tensor, *, config: Mapping[str, Any] | None = None) -> Mapper:
        """The ``mean-da`` control: always the mean of the training w_DA rows ``[N, d]``."""
        w = _as_float32(w_da_train)
        if w.ndim != 2 or w.shape[0] == 0:
            raise UserError(f"mean-da needs training rows [N, d] with N >= 1, got shape {tuple(w.shape)}")
        return cls(kind="mean-da", dim=w.shape[1], constant=w.mean(dim=0), config=config or {"kind": "mean-da"})

    @classmethod
    def pistar_head(cls, head: np.ndarray | torch.Tensor, *, config: Mapping[str, Any] | None = None) -> Mapper:
        """The ``pistar-head`` control: always ``head`` (pi*'s own head vector, 1-D)."""
        v = _as_float32(head)
        if v.ndim != 1 or v.numel() == 0:
            raise UserError(f"pistar_head must be a non-empty 1-D head vector, got shape {tuple(v.shape)}; pass pi*'s policy.head_vector()")
        return cls(kind="pistar-head", dim=v.shape[0], constant=v.clone(), config=config or {"kind": "pistar-head"})

    @property
    def in_dim(self) -> int:
        """Length of the head vectors this mapper takes and returns."""
        return self.dim

    def __call__(self, w_bc: np.ndarray | torch.Tensor) -> np.ndarray:
        """Map one flat head vector ``[d]`` to the w_DA estimate ``[d]`` (float32, eval mode)."""
        w = _as_float32(w_bc)
        if w.ndim != 1:
            raise UserError(
                f"mapper input must be a 1-D head vector, got shape {tuple(w.shape)}; pass policy.head_vector() (map_batch takes [N, {self.dim}])"
            )
        return self.map_batch(w[None])[0]

    def map_batch(self, w_bc: np.ndarray | torch.Tensor) -> np.ndarray:
        """Map rows ``[N, d]`` of head vectors to w_DA estimates ``[N, d]`` (float32, eval mode)."""
        w = _as_float32(w_bc)
        if w.ndim != 2:
            raise UserError(f"map_batch takes a 2-D batch [N, {self.dim}], got shape {tuple(w.shape)}; use mapper(w) for one vector")
        if w.shape[1] != self.dim:
            raise UserError(
                f"mapper input has the wrong length: got {w.shape[1]}, expected {self.dim}: "
                "the head of the policy the mapper was trained for (policy.head_vector())"
            )
        return self.map_tensor(w).numpy()

    def map_tensor(self, w: torch.Tensor) -> torch.Tensor:
        """Map a float32 tensor ``[N, d]`` without input checks (eval mode, no gradients)."""
        if self.constant is not None:
            return self.constant.expand(w.shape[0], -1).clone()
        route = ROUTES[self.kind]
        for net in self.networks.values():
            net.eval()
        with torch.inference_mode():
            x = self.scalers[route.in_scaler].transform(w)
            if route.encoder:
                x = self.networks[route.encoder].encode(x)
            x = self.networks[route.core](x)
            if route.decoder:
                x = self.networks[route.decoder].decode(x)
            return self.scalers[route.out_scaler].inverse(x)

    def save(self, path: str | Path) -> Path:
        """Write the mapper as one safetensors file (atomically); :func:`load_mapper` reads it back."""
        tensors: dict[str, torch.Tensor] = {}
        for name, net in self.networks.items():
            tensors.update({f"networks.{name}.{key}": value for key, value in net.state_dict().items()})
        for name, scaler in self.scalers.items():
            tensors[f"scalers.{name}.mean"] = scaler.mean
            tensors[f"scalers.{name}.std"] = scaler.std
        if self.constant is not None:
            tensors["constant"] = self.constant
        metadata = {
            "format": _FORMAT,
            "format_version": str(_FORMAT_VERSION),
            "kind": self.kind,
            "dim": str(self.dim),
            "config": json.dumps(self.config, sort_keys=True),
            "metadagger_version": __version__,
        }
        return save_tensors(path, tensors, metadata=metadata)


def load_mapper(path: str | Path) -> Mapper:
    """Rebuild a mapper written by :meth:`Mapper.save`.

    Raises:
        CheckpointError: the file is missing, corrupt, not a mapper, or its tensors do not fit
            the architecture its metadata describes.
    """
    tensors = load_tensors(path, what="mapper")
    meta = read_metadata(path, what="mapper")
    if meta.get("format") != _FORMAT:
        raise CheckpointError(f"{path} is not a mapper file (no {_FORMAT!r} metadata); pass a mapper.safetensors written by train-mapper")
    try:
        kind = meta["kind"]
        dim = int(meta["dim"])
        config = json.loads(meta["config"])
        if kind not in KINDS:
            raise ValueError(f"unknown kind {kind!r}")
        if kind in CONTROL_KINDS:
            return Mapper(kind=kind, dim=dim, constant=tensors["constant"], config=config)
        # A throwaway generator: rebuilding must not consume the caller's global torch RNG.
        arch = {field: config[field] for field in ARCH_FIELDS}
        networks = build_networks(kind, dim, **arch, generator=torch.Generator().manual_seed(0))
        for name, net in networks.items():
            prefix = f"networks.{name}."
            net.load_state_dict({k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}, strict=True)
        scalers = {
            name: Standardizer(mean=tensors[f"scalers.{name}.mean"], std=tensors[f"scalers.{name}.std"])
            for name in {ROUTES[kind].in_scaler, ROUTES[kind].out_scaler}
        }
        return Mapper(kind=kind, dim=dim, networks=networks, scalers=scalers, config=config)
    except (KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise CheckpointError(f"mapper file {path} does not match its own metadata ({exc}); delete it and re-run train-mapper") from None


@functools.lru_cache(maxsize=8)
def cached_mapper(path: str) -> Mapper:
    """:func:`load_mapper`, once per worker process and path (callers must not change it)."""
    return load_mapper(path)


def _as_float32(w: Any) -> torch.Tensor:
    if isinstance(w, torch.Tensor):
        t = w.detach().to("cpu")
    else:
        try:
            t = torch.from_numpy(np.ascontiguousarray(w))
        except TypeError:
            raise UserError(f"mapper input must be a float array or tensor, got {type(w).__name__}") from None
    if not t.is_floating_point():
        raise UserError(f"mapper input must be a float array, got dtype {t.dtype}; pass policy.head_vector()")
    return t.to(torch.float32)
