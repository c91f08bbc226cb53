"""The per-seed pair store ``runs/<name>/pairs/``, safe to kill and resume.

Layout:
    ``<seed>.safetensors``  tensors ``w_bc`` and ``w_da``: the head after BC and after DAgger
                            (flat float32 vectors of one length), and ``context``, the seed's
                            context (:func:`metadagger.metal_dagger.method.seed_context`; absent in pairs stored
                            without one), written atomically;
    ``pairs.jsonl``         one JSON line per seed: ``seed``, ``bc`` and ``da`` outcomes
                            (success, reward, steps, expert_queries), ``kept`` and free-form fields.

A seed's tensors are written before its JSON line, and the line is flushed and fsynced, so a line
never points at a missing file. A seed counts as done only when its line is complete and its file
loads; a SIGKILL can leave a torn last line (ignored, and cut off by the next append) or a
``.tmp`` file (ignored, and removed when that seed is written again).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file

from metadagger.errors import CheckpointError, DivergedError, UserError
from metadagger.utils.io import save_tensors
from metadagger.utils.jsonl import append_line, read_lines

__all__ = ["OUTCOME_KEYS", "PairSplit", "PairStore"]

OUTCOME_KEYS = ("success", "reward", "steps", "expert_queries")
"""Keys every ``bc`` and ``da`` outcome in a record must have."""

_JSONL = "pairs.jsonl"
_RECOLLECT = "run metadagger pairs, which collects that pair again"


@dataclass(frozen=True, eq=False)  # eq=False: == on tensors is elementwise, not a bool
class PairSplit:
    """Train and validation pairs, rows in the order of the seeds.

    Attributes:
        w_bc_train: ``[n_train, d]`` float32, heads after BC (the mapper's input).
        w_da_train: ``[n_train, d]`` float32, heads after DAgger (the mapper's target).
        w_bc_val: ``[n_val, d]`` float32.
        w_da_val: ``[n_val, d]`` float32.
        train_seeds: the seeds of the training rows, ascending.
        val_seeds: the seeds of the validation rows, ascending.
        context_train: ``[n_train, k]`` float32, the seeds' contexts; None when a pair has none.
        context_val: ``[n_val, k]`` float32, or None with ``context_train``.
    """

    w_bc_train: torch.Tensor
    w_da_train: torch.Tensor
    w_bc_val: torch.Tensor
    w_da_val: torch.Tensor
    train_seeds: tuple[int, ...]
    val_seeds: tuple[int, ...]
    context_train: torch.Tensor | None = None
    context_val: torch.Tensor | None = None

    def __post_init__(self) -> None:
        dim = self.w_bc_train.shape[-1]
        for name, seeds in (("train", self.train_seeds), ("val", self.val_seeds)):
            for kind in ("w_bc", "w_da"):
                field = f"{kind}_{name}"
                shape = tuple(getattr(self, field).shape)
                if shape != (len(seeds), dim):
                    raise ValueError(
                        f"PairSplit.{field} has shape {shape}, expected {(len(seeds), dim)} ({len(seeds)} {name}_seeds)"
                    )
        if (self.context_train is None) != (self.context_val is None):
            raise ValueError("PairSplit.context_train and context_val must both be given or both be None")
        if self.context_train is not None:
            width = self.context_train.shape[-1]
            for name, seeds in (("train", self.train_seeds), ("val", self.val_seeds)):
                shape = tuple(getattr(self, f"context_{name}").shape)
                if shape != (len(seeds), width):
                    raise ValueError(
                        f"PairSplit.context_{name} has shape {shape}, expected {(len(seeds), width)} ({len(seeds)} "
                        f"{name}_seeds)"
                    )
        if set(self.train_seeds) & set(self.val_seeds):
            raise ValueError(
                f"PairSplit train_seeds and val_seeds overlap: {sorted(set(self.train_seeds) & set(self.val_seeds))}"
            )

    def with_train_rows(self, rows: torch.Tensor) -> PairSplit:
        """The same validation pairs with only the training rows at indices ``rows``."""
        return dataclasses.replace(
            self,
            w_bc_train=self.w_bc_train[rows],
            w_da_train=self.w_da_train[rows],
            train_seeds=tuple(self.train_seeds[i] for i in rows.tolist()),
            context_train=None if self.context_train is None else self.context_train[rows],
        )


def validation_size(pairs: int, val_fraction: float) -> int:
    """How many of ``pairs`` pairs validate: ``val_fraction`` of them rounded half up, at least one
    when ``val_fraction`` is positive."""
    return max(1, math.floor(val_fraction * pairs + 0.5)) if val_fraction > 0 else 0


class PairStore:
    """Reads and writes the pairs of one run; only the driver process writes.

    Args:
        root: the ``pairs/`` folder; created by the first :meth:`write`.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.jsonl_path = self.root / _JSONL

    def pair_path(self, seed: int) -> Path:
        """Return the path of ``seed``'s tensor file."""
        return self.root / f"{_check_seed(seed)}.safetensors"

    def done_seeds(self) -> set[int]:
        """Return the seeds with a complete JSON line and a loadable tensor file (empty if no store)."""
        if not self.root.is_dir():
            return set()
        done = set()
        for seed in self._latest_records():
            try:
                self._read_pair(seed)
            except CheckpointError:
                continue  # e.g. the file was deleted or damaged: that seed is simply redone
            done.add(seed)
        return done

    def write(
        self,
        seed: int,
        w_bc: torch.Tensor,
        w_da: torch.Tensor,
        record: Mapping[str, Any],
        context: torch.Tensor | None = None,
    ) -> None:
        """Store one seed's pair and record; a later write for the same seed supersedes it.

        Args:
            seed: the task instance, a non-negative int.
            w_bc: the head after BC, a 1-D float32 tensor.
            w_da: the head after DAgger, a 1-D float32 tensor of the same length.
            record: ``bc`` and ``da`` outcomes (each with :data:`OUTCOME_KEYS`), ``kept`` (bool) and
                any JSON-serialisable extra fields; ``seed`` is added (or must match).
            context: the seed's context, a 1-D float32 tensor (None: stored without one).

        Raises:
            ValueError: bad seed, tensors or record (nothing is written then).
        """
        seed = _check_seed(seed)
        for name, tensor in (("w_bc", w_bc), ("w_da", w_da), ("context", context)):
            if (
                isinstance(tensor, torch.Tensor)
                and tensor.is_floating_point()
                and not bool(torch.isfinite(tensor).all())
            ):
                raise DivergedError(
                    f"refusing to write the pair of seed {seed}: its {name} holds NaN or infinite values, "
                    "so the fits that made it diverged; nothing was written"
                )
        _check_vectors(w_bc, w_da)
        if context is not None:
            _check_context(context)
        line = _record_line(seed, record)
        self.root.mkdir(parents=True, exist_ok=True)
        for stale in self.root.glob(f".{seed}.safetensors.*.tmp"):
            stale.unlink()  # left by a kill inside an atomic write; only this process writes here
        tensors = {"w_bc": w_bc, "w_da": w_da} | ({} if context is None else {"context": context})
        save_tensors(self.pair_path(seed), tensors, metadata={"seed": str(seed)})
        append_line(self.jsonl_path, line)

    def check_readable(self, seeds: Iterable[int], *, fix: str = _RECOLLECT) -> None:
        """Raise a :class:`CheckpointError` for the first of ``seeds`` that has a record but whose
        file is missing, corrupt or not a pair (the seeds :meth:`done_seeds` leaves out for that):
        the file, what is wrong with it, then ``fix``."""
        recorded = self._latest_records()
        for seed in seeds:
            if seed in recorded:
                self._read_pair(seed, fix=fix)

    def records(self) -> list[dict[str, Any]]:
        """Return the last record of every seed, sorted by seed.

        Raises:
            UserError: the store folder does not exist.
            CheckpointError: a complete line of ``pairs.jsonl`` is not a JSON record.
        """
        self._require_root()
        latest = self._latest_records()
        return [latest[seed] for seed in sorted(latest)]

    def load(self, seeds: Iterable[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(W_bc, W_da)``, each ``[len(seeds), d]`` float32, rows in the order given.

        Raises:
            UserError: no store folder, or no seeds given.
            CheckpointError: a seed has no record, or its file is missing, corrupt or of another shape.
        """
        return _stacked(self._load_files(seeds))

    def load_contexts(self, seeds: Iterable[int]) -> torch.Tensor | None:
        """The contexts of ``seeds`` (stored pairs), ``[len(seeds), k]`` float32 in the order given;
        None when any of them was stored without one.

        Raises:
            CheckpointError: a file is missing or corrupt, or the contexts differ in length.
        """
        return self._contexts(self._load_files(seeds))

    def _contexts(self, files: list[dict[str, torch.Tensor]]) -> torch.Tensor | None:
        contexts = [tensors.get("context") for tensors in files]
        if not contexts or any(c is None for c in contexts):
            return None
        lengths = sorted({c.shape[0] for c in contexts})
        if len(lengths) > 1:
            raise CheckpointError(
                f"the pairs in {self.root} hold contexts of lengths {lengths}: pairs from different policies "
                "are mixed; re-run metadagger pairs --rebuild"
            )
        return torch.stack(contexts)

    def stamps(self) -> dict[int, dict[str, Any]]:
        """For the per-seed driver (:mod:`metadagger.runfolder.driver`): each done seed's ``{"pair": stamp}``
        (what its pair was made from).

        Raises:
            CheckpointError: a done seed's record holds no stamp (a corrupt line).
        """
        done = self.done_seeds()
        if not done:
            return {}
        stamps = {}
        for seed, record in self._latest_records().items():
            if seed not in done:
                continue
            if "stamp" not in record:
                raise CheckpointError(
                    f"{self.jsonl_path} has a pair record without its stamp (seed {seed}); "
                    "delete that line and re-run metadagger pairs"
                )
            stamps[seed] = {"pair": record["stamp"]}
        return stamps

    def append(self, result: Mapping[str, Any], stamps: Mapping[str, Any]) -> None:
        """For the per-seed driver: store a collected pair (``seed``, ``w_bc``, ``w_da``, ``record``)
        with the stamp it was made from."""
        # np.array copies: arrays from Ray workers are read-only, which torch warns about
        context = result.get("context")
        self.write(
            result["seed"],
            torch.from_numpy(np.array(result["w_bc"])),
            torch.from_numpy(np.array(result["w_da"])),
            {**result["record"], "stamp": dict(stamps["pair"])},
            context=None if context is None else torch.from_numpy(np.array(context)),
        )

    def load_split(
        self, *, val_fraction: float, seed: int, kept_only: bool = True, seeds: Iterable[int] | None = None
    ) -> PairSplit:
        """Split the stored pairs into train and validation sets by a seeded permutation.

        Args:
            val_fraction: share of the pairs for validation, in ``[0, 1)``; when positive, at
                least one pair (rounded to the nearest count otherwise).
            seed: seeds the permutation; the same store and seed give the same split.
            kept_only: use only records with ``kept`` true (BC failed and DAgger succeeded).
            seeds: use only these seeds' records (default: every recorded seed).

        Raises:
            UserError: bad ``val_fraction``, or too few pairs for a training set.
        """
        if not isinstance(val_fraction, (int, float)) or not 0.0 <= val_fraction < 1.0:
            raise UserError(
                f"val_fraction must be in [0, 1), got {val_fraction!r}; e.g. 0.2 holds out a fifth of the pairs"
            )
        wanted = None if seeds is None else set(seeds)
        seeds = [
            r["seed"]
            for r in self.records()
            if (r.get("kept") is True or not kept_only) and (wanted is None or r["seed"] in wanted)
        ]
        n_val = validation_size(len(seeds), val_fraction)
        if len(seeds) - n_val < 1:
            which = "kept pairs" if kept_only else "pairs"
            raise UserError(
                f"{self.root} has {len(seeds)} {which}, too few for a training set with val_fraction={val_fraction}; "
                "collect more seeds (metadagger pairs) or lower val_fraction"
            )
        order = np.random.default_rng(seed).permutation(len(seeds))
        val_seeds = tuple(sorted(seeds[i] for i in order[:n_val]))
        train_seeds = tuple(sorted(seeds[i] for i in order[n_val:]))
        files = self._load_files(train_seeds + val_seeds)  # each file read once
        w_bc, w_da = _stacked(files)
        contexts = self._contexts(files)
        n_train = len(train_seeds)
        return PairSplit(
            w_bc_train=w_bc[:n_train],
            w_da_train=w_da[:n_train],
            w_bc_val=w_bc[n_train:],
            w_da_val=w_da[n_train:],
            train_seeds=train_seeds,
            val_seeds=val_seeds,
            context_train=None if contexts is None else contexts[:n_train],
            context_val=None if contexts is None else contexts[n_train:],
        )

    def _require_root(self) -> None:
        if not self.root.is_dir():
            raise UserError(
                f"pair store not found: {self.root} (expected the pairs/ folder of a run); check --out or run "
                "metadagger pairs first"
            )

    def _latest_records(self) -> dict[int, dict[str, Any]]:
        latest: dict[int, dict[str, Any]] = {}
        for record in read_lines(self.jsonl_path, called="pair record"):
            try:
                seed = _check_seed(record.get("seed") if isinstance(record, Mapping) else None)
                _record_line(seed, record)
                if not isinstance(record.get("stamp", {}), Mapping):
                    raise ValueError(f"record 'stamp' must be a mapping, got {record['stamp']!r}")
            except ValueError as exc:
                raise CheckpointError(
                    f"{self.jsonl_path} has a damaged pair record ({exc}): {str(record)[:80]}; delete that line and "
                    "re-run "
                    "metadagger pairs (it collects the seed again)"
                ) from None
            latest[seed] = record
        return latest

    def _load_files(self, seeds: Iterable[int]) -> list[dict[str, torch.Tensor]]:
        """The checked tensors of each of ``seeds``' pair files, in the order given (see :meth:`load`)."""
        self._require_root()
        seeds = [_check_seed(s) for s in seeds]
        if not seeds:
            raise UserError(f"no seeds given to load from {self.root}; pass at least one seed that records() lists")
        recorded = self._latest_records()
        files = []
        for seed in seeds:
            if seed not in recorded:
                raise CheckpointError(
                    f"seed {seed} has no record in {self.jsonl_path}; collect it first (metadagger pairs resumes "
                    "missing seeds)"
                )
            files.append(self._read_pair(seed))
        dim = files[0]["w_bc"].shape[0]
        for seed, tensors in zip(seeds, files):
            w_bc = tensors["w_bc"]
            if w_bc.shape[0] != dim:
                raise CheckpointError(
                    f"pair file {self.pair_path(seed)} holds vectors of length {w_bc.shape[0]}, but seed {seeds[0]} "
                    "has "
                    f"length {dim}; pairs from different policies are mixed: delete the odd files and re-run "
                    "metadagger pairs"
                )
        return files

    def _read_pair(self, seed: int, *, fix: str = _RECOLLECT) -> dict[str, torch.Tensor]:
        path = self.pair_path(seed)
        try:
            return _pair_tensors(path)
        except ValueError as exc:
            raise CheckpointError(f"pair file {path} {exc}; {fix}") from None


def _pair_tensors(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of a pair file; a ValueError says what is wrong with the file."""
    if not path.is_file():
        raise ValueError("is missing")
    try:
        tensors = load_file(str(path))
    except Exception as exc:  # safetensors raises several types for corrupt headers
        raise ValueError(f"is corrupt or not a safetensors file ({exc})") from None
    try:
        _check_pair(tensors)
    except ValueError as exc:
        raise ValueError(f"is not a valid pair ({exc})") from None
    return tensors


def _check_pair(tensors: Mapping[str, Any]) -> None:
    """Raise a ValueError unless ``tensors`` are a pair: ``w_bc``, ``w_da`` and optionally ``context``."""
    if not {"w_bc", "w_da"} <= tensors.keys() <= {"w_bc", "w_da", "context"}:
        raise ValueError(f"it holds tensors {sorted(tensors)}, expected w_bc, w_da and optionally context")
    _check_vectors(tensors["w_bc"], tensors["w_da"])
    if "context" in tensors:
        _check_context(tensors["context"])


def _stacked(files: list[dict[str, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.stack([f["w_bc"] for f in files]), torch.stack([f["w_da"] for f in files])


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def _check_vectors(w_bc: Any, w_da: Any) -> None:
    for name, w in (("w_bc", w_bc), ("w_da", w_da)):
        if not isinstance(w, torch.Tensor):
            raise ValueError(f"{name} must be a torch.Tensor, got {type(w).__name__}")
        if w.dtype != torch.float32 or w.ndim != 1 or w.numel() == 0:
            raise ValueError(f"{name} must be a non-empty 1-D float32 tensor, got {w.dtype} of shape {tuple(w.shape)}")
        if not bool(torch.isfinite(w).all()):
            raise ValueError(f"{name} holds NaN or infinite values")
    if w_bc.shape != w_da.shape:
        raise ValueError(f"w_bc and w_da must have the same length, got {w_bc.shape[0]} and {w_da.shape[0]}")


def _check_context(context: Any) -> None:
    if not isinstance(context, torch.Tensor) or context.dtype != torch.float32 or context.ndim != 1:
        raise ValueError(
            f"context must be a 1-D float32 tensor, got {getattr(context, 'dtype', type(context).__name__)} "
            f"of shape {tuple(getattr(context, 'shape', ()))}"
        )
    if not bool(torch.isfinite(context).all()):
        raise ValueError("context holds NaN or infinite values")


def _record_line(seed: int, record: Mapping[str, Any]) -> bytes:
    if not isinstance(record, Mapping):
        raise ValueError(f"record must be a mapping, got {type(record).__name__}")
    if "seed" in record and record["seed"] != seed:
        raise ValueError(f"record seed {record['seed']!r} does not match the seed written, {seed}")
    if not isinstance(record.get("kept"), (bool, np.bool_)):
        raise ValueError(f"record 'kept' must be a bool, got {record.get('kept')!r}")
    for phase in ("bc", "da"):
        outcome = record.get(phase)
        missing = [k for k in OUTCOME_KEYS if not isinstance(outcome, Mapping) or k not in outcome]
        if missing:
            raise ValueError(f"record {phase!r} must be a mapping with keys {OUTCOME_KEYS}, missing {missing}")
    try:
        # Sorted keys and no timestamps: identical inputs give byte-identical files.
        text = json.dumps({**record, "seed": seed}, sort_keys=True, separators=(",", ":"), default=_json_scalar)
    except TypeError as exc:
        raise ValueError(f"record for seed {seed} is not JSON-serialisable: {exc}") from None
    return (text + "\n").encode()


def _json_scalar(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
