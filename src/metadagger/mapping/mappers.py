"""Mappers f: w_BC -> estimate of w_DA on flat head vectors (paper section 3.3), saved and loaded.

The kinds (DM, SAM, TAM, ridge, modes, conditioned and the controls mean-DA and pi*-head) are
declared in :mod:`metadagger.mapping.registry`. A kind with a context (``conditioned``) also takes
the seed's context (:func:`metadagger.metal_dagger.method.seed_context`) beside w_BC.

Every learned kind works in standardised space: a :class:`Standardizer` per data set, fitted on
the training split only and saved with the mapper. A mapper is one safetensors file whose
metadata holds kind, length and architecture, so :func:`load_mapper` rebuilds it without pickle.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from metadagger.errors import CheckpointError, UserError
from metadagger.mapping.registry import get_kind
from metadagger.policies import tensor_mismatch
from metadagger.runfolder.stamps import file_fingerprint
from metadagger.utils.io import load_tensors, read_metadata, save_tensors
from metadagger.version import __version__

__all__ = ["ARCH_FIELDS", "Mapper", "MapperFile", "Standardizer", "build_networks", "cached_mapper", "load_mapper"]

#: Tensors of a mapper file where -inf marks an unused entry: the modes kind's empty groups
#: (:class:`~metadagger.mapping.modes.GroupMeans`). Anywhere else a non-finite value is damage.
MASKED_TENSORS = frozenset({"networks.modes.bias"})
ARCH_FIELDS = ("hidden", "latent", "ae_hidden", "batchnorm", "dropout", "ae_dropout")
"""The config fields that decide the networks' shapes (stored with every mapper)."""

_FORMAT = "metadagger.mapper"
_FORMAT_VERSION = 1


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
            raise ValueError(
                f"mean and std must be 1-D of one length, got shapes {tuple(mean.shape)} and {tuple(std.shape)}"
            )
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
    kind: str, dim: int, *, context_dim: int = 0, generator: torch.Generator | None = None, **arch: Any
) -> dict[str, nn.Module]:
    """The untrained networks of a learned kind (``arch``: the :data:`ARCH_FIELDS`; ``context_dim``:
    the context's length, for a kind with a context); none for a control."""
    spec = get_kind(kind)
    if not spec.build:
        return {}
    return spec.build(dim, generator=generator, **arch, **({"context_dim": context_dim} if spec.context else {}))


class Mapper:
    """A trained mapping f: w_BC -> w_DA estimate, callable on flat float32 head vectors.

    Build one with :func:`metadagger.mapping.train.train_mapper`, :meth:`mean_da`,
    :meth:`pistar_head` or :func:`load_mapper`.

    Args:
        kind: a kind of :mod:`metadagger.mapping.registry`.
        dim: length of the head vectors.
        networks: the trained modules, named as in the kind's route (learned kinds).
        scalers: the standardisers, named as in the kind's route (learned kinds).
        constant: the vector a control always returns (controls).
        config: the training config as plain JSON data; its :data:`ARCH_FIELDS` rebuild the networks.
        stamp: what it was made from (config and the fingerprint of its training data), saved with it.
        context_dim: the length of the context a kind with a context reads (0 for the others).
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
        stamp: Mapping[str, Any] | None = None,
        context_dim: int = 0,
    ) -> None:
        spec = get_kind(kind)
        self.kind = kind
        self.dim = int(dim)
        self.context_dim = int(context_dim)
        if spec.context != (self.context_dim > 0):
            raise ValueError(
                f"a {kind} mapper needs context_dim {'> 0' if spec.context else '= 0'}, got {self.context_dim}"
            )
        self.networks = dict(networks or {})
        self.scalers = dict(scalers or {})
        self.constant = constant
        self.config = dict(config or {})
        self.stamp = dict(stamp or {})
        if not spec.learned:
            if constant is None or tuple(constant.shape) != (self.dim,) or constant.dtype != torch.float32:
                got = None if constant is None else f"{constant.dtype} {tuple(constant.shape)}"
                raise ValueError(f"a {kind} mapper needs a float32 constant of shape ({self.dim},), got {got}")
        elif set(self.networks) != set(spec.network_names) or set(self.scalers) != set(spec.scaler_names):
            raise ValueError(
                f"a {kind} mapper needs networks {sorted(spec.network_names)} and scalers {sorted(spec.scaler_names)}, "
                f"got {sorted(self.networks)} and {sorted(self.scalers)}"
            )

    @classmethod
    def mean_da(cls, w_da_train: np.ndarray | torch.Tensor, *, config: Mapping[str, Any] | None = None) -> Mapper:
        """The ``mean-da`` control: always the mean of the training w_DA rows ``[N, d]``."""
        return cls.control("mean-da", w_da_train=_as_float32(w_da_train), config=config)

    @classmethod
    def pistar_head(cls, head: np.ndarray | torch.Tensor, *, config: Mapping[str, Any] | None = None) -> Mapper:
        """The ``pistar-head`` control: always ``head`` (pi*'s own head vector, 1-D)."""
        return cls.control("pistar-head", pistar_head=_as_float32(head), config=config)

    @classmethod
    def control(
        cls,
        kind: str,
        *,
        w_da_train: torch.Tensor | None = None,
        pistar_head: torch.Tensor | None = None,
        config: Mapping[str, Any] | None = None,
    ) -> Mapper:
        """The control ``kind``, its constant computed from the training w_DA rows or pi*'s head."""
        spec = get_kind(kind)
        if spec.constant is None:
            raise UserError(f"mapper kind {kind!r} is learned, not a control; train it with train_mapper")
        w_da = torch.zeros(0, 0) if w_da_train is None else w_da_train
        constant = spec.constant(w_da, pistar_head).to(torch.float32)
        return cls(kind=kind, dim=constant.shape[0], constant=constant, config=config or {"kind": kind})

    @property
    def in_dim(self) -> int:
        """Length of the head vectors this mapper takes and returns."""
        return self.dim

    @property
    def needs_context(self) -> bool:
        """Whether the mapper reads the seed's context beside w_BC."""
        return self.context_dim > 0

    def __call__(self, w_bc: np.ndarray | torch.Tensor, context: np.ndarray | torch.Tensor | None = None) -> np.ndarray:
        """Map one flat head vector ``[d]`` (and, for a kind with a context, the seed's context
        ``[k]``) to the w_DA estimate ``[d]`` (float32, eval mode)."""
        w = _as_float32(w_bc)
        if w.ndim != 1:
            raise UserError(
                f"mapper input must be a 1-D head vector, got shape {tuple(w.shape)}; pass policy.head_vector() "
                f"(map_batch takes [N, {self.dim}])"
            )
        return self.map_batch(w[None], None if context is None else _as_float32(context)[None])[0]

    def map_batch(
        self, w_bc: np.ndarray | torch.Tensor, context: np.ndarray | torch.Tensor | None = None
    ) -> np.ndarray:
        """Map rows ``[N, d]`` of head vectors (and, for a kind with a context, the seeds' contexts
        ``[N, k]``; ignored by the others) to w_DA estimates ``[N, d]`` (float32, eval mode)."""
        w = _as_float32(w_bc)
        if w.ndim != 2:
            raise UserError(
                f"map_batch takes a 2-D batch [N, {self.dim}], got shape {tuple(w.shape)}; use mapper(w) for one vector"
            )
        if w.shape[1] != self.dim:
            raise UserError(
                f"mapper input has the wrong length: got {w.shape[1]}, expected {self.dim}: "
                "the head of the policy the mapper was trained for (policy.head_vector())"
            )
        if not self.needs_context:
            return self.map_tensor(w).numpy()
        if context is None:
            raise UserError(
                f"the {self.kind} mapper needs the seed's context beside w_BC "
                "(metadagger.metal_dagger.method.seed_context), got none"
            )
        c = _as_float32(context)
        if tuple(c.shape) != (w.shape[0], self.context_dim):
            raise UserError(
                f"the {self.kind} mapper's context has shape {tuple(c.shape)}, expected "
                f"{(w.shape[0], self.context_dim)}: "
                "one context per head, of the pi* the mapper was trained for"
            )
        return self.map_tensor(w, c).numpy()

    def map_tensor(self, w: torch.Tensor, context: torch.Tensor | None = None) -> torch.Tensor:
        """Map a float32 tensor ``[N, d]`` (with ``context`` ``[N, k]`` for a kind with a context)
        without input checks (eval mode, no gradients)."""
        if self.constant is not None:
            return self.constant.expand(w.shape[0], -1).clone()
        route = get_kind(self.kind).route
        for net in self.networks.values():
            net.eval()
        with torch.inference_mode():
            x = self.scalers[route.in_scaler].transform(w)
            if self.needs_context:
                x = torch.cat([x, self.scalers["context"].transform(context)], dim=1)
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
            "stamp": json.dumps(self.stamp, sort_keys=True),
            "metadagger_version": __version__,
        } | ({"context_dim": str(self.context_dim)} if self.context_dim else {})
        return save_tensors(path, tensors, metadata=metadata, masks=MASKED_TENSORS)


def load_mapper(path: str | Path) -> Mapper:
    """Rebuild a mapper written by :meth:`Mapper.save`.

    Raises:
        CheckpointError: the file is missing, corrupt, not a mapper, or its tensors do not fit
            the architecture its metadata describes.
    """
    tensors = load_tensors(path, called="mapper", masks=MASKED_TENSORS)
    meta = read_metadata(path, called="mapper")
    if meta.get("format") != _FORMAT:
        raise CheckpointError(
            f"{path} is not a mapper file (no {_FORMAT!r} metadata); pass a mapper.safetensors written by train-mapper"
        )
    try:
        kind = meta["kind"]
        dim = int(meta["dim"])
        context_dim = int(meta.get("context_dim", "0"))
        config = json.loads(meta["config"])
        stamp = json.loads(meta.get("stamp", "{}"))
        spec = get_kind(kind)
        if not spec.learned:
            return Mapper(kind=kind, dim=dim, constant=tensors["constant"], config=config, stamp=stamp)
        # A throwaway generator: rebuilding must not consume the caller's global torch RNG.
        arch = {field: config[field] for field in ARCH_FIELDS}
        networks = build_networks(
            kind, dim, context_dim=context_dim, **arch, generator=torch.Generator().manual_seed(0)
        )
        mismatch = tensor_mismatch(
            {k: v for k, v in tensors.items() if k.startswith("networks.")},
            {f"networks.{name}.{k}": v for name, net in networks.items() for k, v in net.state_dict().items()},
        )
        if mismatch:
            raise ValueError(mismatch)
        for name, net in networks.items():
            prefix = f"networks.{name}."
            net.load_state_dict({k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}, strict=True)
        scalers = {
            name: Standardizer(mean=tensors[f"scalers.{name}.mean"], std=tensors[f"scalers.{name}.std"])
            for name in spec.scaler_names
        }
        return Mapper(
            kind=kind, dim=dim, networks=networks, scalers=scalers, config=config, stamp=stamp, context_dim=context_dim
        )
    except UserError as exc:
        raise CheckpointError(f"mapper file {path}: {exc}; delete it and re-run train-mapper") from None
    except (KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise CheckpointError(
            f"mapper file {path} does not match its own metadata ({exc}); delete it and re-run train-mapper"
        ) from None


@dataclass(frozen=True)
class MapperFile:
    """A mapper file as a stage's stamps recorded it: its path and the fingerprint of its bytes."""

    path: str
    fingerprint: str


@functools.lru_cache(maxsize=8)
def cached_mapper(file: MapperFile) -> Mapper:
    """:func:`load_mapper`, once per worker process and file (callers must not change it),
    checked to be the bytes the stage's stamps fingerprinted: a file replaced while the stage
    runs is a :class:`UserError`, never results under the old mapper's name."""
    mapper = load_mapper(file.path)
    if file_fingerprint(file.path) != file.fingerprint:
        raise UserError(
            f"mapper file {file.path} changed while this stage ran (another process rewrote it); "
            "run the stage again once that process is done"
        )
    return mapper


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
