"""Atomic artifact writing: a temporary file in the same folder, then ``os.replace``.

A killed process therefore never leaves a half-written file under an artifact's final name.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable, Collection

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from metadagger.errors import CheckpointError, DivergedError, UserError


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def make_folder(folder: Path) -> None:
    """Create ``folder`` and its parents; a file in the way, or a place where no folder can be
    made, is a :class:`UserError` naming it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocker = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()), folder)
        raise UserError(
            f"cannot create folder {folder}: {blocker} is a file, not a folder; choose another output path or move "
            "that file"
        ) from None
    except OSError as exc:
        raise UserError(
            f"cannot create folder {folder} ({exc.strerror}); choose an output path you can write to"
        ) from None


def check_writable(folder: str | Path) -> None:
    """Make sure files can be written in ``folder`` (created if missing), before any work that
    ends with writing there: a full disk, a read-only folder or a missing permission is one
    :class:`UserError` naming it and what to do."""
    folder = Path(folder)
    make_folder(folder)
    try:
        fd, probe = tempfile.mkstemp(prefix=".probe.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise machine_fault(folder, exc) or UserError(
            f"cannot write in {folder} ({exc.strerror}); choose a folder you can write to"
        ) from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(path: str | Path, option: str) -> None:
    """Make sure ``path`` (given as ``option``) can be written as a file, before any work that ends
    by writing it: not a folder, and under a writable folder (nothing is created here)."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{option} {path} is a folder; give a file path such as {path / 'result.json'}")
    nearest = next(p for p in (path.parent.absolute(), *path.parent.absolute().parents) if p.exists())
    if not nearest.is_dir():
        raise UserError(
            f"{option} {path}: {nearest} is a file, not a folder; choose another output path or move that file"
        )
    try:
        fd, trial = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=nearest)
    except OSError as exc:
        raise UserError(
            f"{option} {path}: cannot write in {nearest} ({exc.strerror}); choose an output path you can write to"
        ) from None
    os.close(fd)
    os.unlink(trial)


#: The errors of the machine rather than of the code: a full disk, a read-only or forbidden folder.
_MACHINE_FAULTS = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}


def machine_fault(path: str | Path, exc: BaseException) -> UserError | None:
    """The one-line error for a machine fault (full disk, read-only folder, missing permission)
    met while writing ``path``, naming it and what to do; None for any other error."""
    code = getattr(exc, "errno", None)
    if code not in _MACHINE_FAULTS and "No space left on device" not in str(exc):
        return None
    reason = _MACHINE_FAULTS.get(code, "the disk is full")
    fix = (
        "free some space, then run the same command again: finished work is kept"
        if reason.startswith("the disk")
        else "make the folder writable or choose another --out, then run the command again"
    )
    return UserError(f"cannot write {path}: {reason}; {fix}")


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` then rename the temporary file onto ``path``.

    A full disk, a read-only folder or a missing permission is one :class:`UserError` naming
    the path and what to do; the earlier file at ``path``, if any, is left as it was.
    """
    path = Path(path)
    make_folder(path.parent)
    tmp_path = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
        tmp_path = Path(tmp)
        write(tmp_path)
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; artifacts are shared
        os.replace(tmp_path, path)
    except Exception as exc:
        fault = machine_fault(path, exc)
        if fault is None:
            raise
        raise fault from None
    finally:
        if tmp_path is not None and tmp_path.exists():
            tmp_path.unlink()
    return path


def atomic_folder(path: str | Path, write: Callable[[Path], None], *, staging_in: str | Path | None = None) -> Path:
    """Call ``write(tmp_folder)`` then put that folder at ``path``, replacing what was there.

    ``staging_in`` holds the temporary folder (default: ``path``'s parent; it must be on the same
    filesystem); a failure or a kill leaves ``path`` as it was and no half-written folder under it.
    """
    path = Path(path)
    staging_root = path.parent if staging_in is None else Path(staging_in)
    make_folder(staging_root)
    make_folder(path.parent)
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=staging_root))
    old = staging.with_name(staging.name + ".old")
    try:
        os.chmod(staging, 0o777 & ~_UMASK)  # mkdtemp makes 0700 folders; artifacts are shared
        write(staging)
        if path.exists():
            path.rename(old)
        staging.rename(path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    return atomic_write(path, lambda p: p.write_text(text))


def write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON atomically."""
    return write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def read_json(path: str | Path, called: str) -> Any:
    """The JSON document at ``path`` (an artifact described as ``called``); a missing, unreadable or
    corrupt file is a :class:`UserError` naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(
            f"{called} not found: {path}; re-run the stage that writes it (`metadagger reproduce` resumes a run)"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise corrupt_artifact(called, path, exc.strerror if isinstance(exc, OSError) else str(exc)) from None


def corrupt_artifact(called: str, path: str | Path, reason: str) -> UserError:
    """The error for an artifact that exists but cannot be read: it names the file, why, and the fix."""
    return UserError(
        f"{called} is corrupt or unreadable: {path} ({reason}); delete it and re-run the stage that writes it "
        "(`metadagger reproduce` resumes a run)"
    )


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


# safetensors keeps header metadata in a hash map whose order varies between processes; one key
# holding sorted JSON makes identical inputs give byte-identical files.
_METADATA_KEY = "metadagger"


def _non_finite(name: str, tensor: torch.Tensor, masks: Collection[str]) -> bool:
    """Whether ``tensor`` holds a NaN or an infinity; in a tensor named in ``masks``, -inf marks
    an unused entry (a mapper's empty group) and is allowed."""
    if not tensor.is_floating_point():
        return False
    if name in masks:
        return bool(torch.isnan(tensor).any() or (tensor == float("inf")).any())
    return not bool(torch.isfinite(tensor).all())


def save_tensors(
    path: str | Path,
    tensors: dict[str, torch.Tensor],
    metadata: dict[str, str] | None = None,
    *,
    masks: Collection[str] = (),
) -> Path:
    """Save tensors as safetensors atomically (contiguous CPU copies); same inputs, same bytes.

    ``masks`` names the tensors where -inf marks an unused entry.

    Raises:
        DivergedError: a tensor holds a NaN or an infinity (nothing is written: a non-finite
            tensor is never saved).
    """
    clean = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    for name, tensor in clean.items():
        if _non_finite(name, tensor, masks):
            raise DivergedError(
                f"refusing to write {path}: its tensor {name!r} holds NaN or infinite values, so the "
                "computation that made it diverged; nothing was written"
            )
    header = {_METADATA_KEY: json.dumps(metadata or {}, sort_keys=True)}
    return atomic_write(path, lambda p: save_file(clean, str(p), metadata=header))


def load_tensors(
    path: str | Path, called: str = "checkpoint", *, masks: Collection[str] = ()
) -> dict[str, torch.Tensor]:
    """Load a safetensors file, turning a missing or corrupt file into a :class:`CheckpointError`."""
    path = _tensor_file(path, called)
    try:
        tensors = load_file(str(path))
    except Exception as exc:  # safetensors raises several types for corrupt headers
        raise CheckpointError(
            f"{called} is corrupt or not a safetensors file: {path} ({exc}); delete it and re-run the stage that "
            "writes it"
        ) from None
    for name, tensor in tensors.items():
        if tensor.is_floating_point() and tensor.dtype != torch.float32:
            raise CheckpointError(
                f"{called} {path} holds tensor {name!r} as {str(tensor.dtype).removeprefix('torch.')}, expected "
                "float32; it was not written by metadagger: re-run the stage that writes it"
            )
        if _non_finite(name, tensor, masks):
            raise CheckpointError(
                f"{called} {path} holds NaN or infinite values in tensor {name!r}; it is damaged: delete it "
                "and re-run the stage that writes it"
            )
    return tensors


def _tensor_file(path: str | Path | None, called: str) -> Path:
    """``path`` as a Path, if it names an existing safetensors file; else the one-line error that
    says called was given and called is expected."""
    if not isinstance(path, (str, Path)):
        raise CheckpointError(f"{called}: expected the path of a .safetensors file, got {path!r}")
    path = Path(path)
    if path.is_dir():
        found = sorted(p.name for p in path.glob("*.safetensors"))[:3]
        hint = f" (it holds {', '.join(found)})" if found else ""
        raise CheckpointError(f"{called}: {path} is a folder{hint}; pass the .safetensors file itself")
    if not path.is_file():
        raise CheckpointError(
            f"{called} not found: {path} (expected a .safetensors file; check the path or re-run the stage that writes "
            "it)"
        )
    if path.suffix != ".safetensors":
        raise CheckpointError(
            f"{called}: {path} is not a .safetensors file; pass a file that metadagger wrote "
            "(a policy: RUN/pistar/policy.safetensors; a mapper: RUN/mappers/KIND/mapper.safetensors)"
        )
    return path


def read_metadata(path: str | Path, called: str = "checkpoint") -> dict[str, str]:
    """Return the string metadata stored in a safetensors header."""
    from safetensors import safe_open

    path = _tensor_file(path, called)
    try:
        with safe_open(str(path), framework="pt") as f:
            header = dict(f.metadata() or {})
        return json.loads(header[_METADATA_KEY]) if _METADATA_KEY in header else header
    except Exception as exc:
        raise CheckpointError(
            f"{called} is corrupt or not a safetensors file: {path} ({exc}); delete it and re-run the stage that "
            "writes it"
        ) from None
