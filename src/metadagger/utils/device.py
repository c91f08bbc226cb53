"""Where a process computes: the CPU, or a CUDA GPU.

A run folder is made on one device (``RunConfig.device``, chosen with ``--device`` when the run
starts, never mixed afterwards). Each stage calls :func:`use_device` with it in the driver, and
every executor starts its workers on the same device (:mod:`metadagger.utils.executors`). Code
that computes asks :func:`compute_device` where to put its tensors: the lanes' trunk forwards,
the batched head fits and pi*'s whole-network fits. Everything else (the envs, the experts, the
mappers, single-episode rollouts) stays on the CPU, and every artifact is saved from CPU tensors.

On a GPU the run is made deterministic for one kind of GPU: deterministic algorithms (an op
without one is an error, not a silent difference), cuBLAS's fixed workspace, no cuDNN autotuning
and no TF32. Its stamps name the GPU (:func:`device_stamp`), so artifacts made on another kind of
GPU, or on the CPU, are stale, never mixed in. On the CPU nothing is stamped: CPU artifacts made
before the option existed stay current.
"""

from __future__ import annotations

import os
from typing import Any

from metadagger.errors import UserError

#: The values of ``--device``: ``auto`` takes ``cuda`` where a GPU is visible, else ``cpu``.
DEVICE_CHOICES = ("cpu", "cuda", "auto")

_current = "cpu"


def resolve_device(choice: str) -> str:
    """``cpu`` or ``cuda`` for a ``--device`` value; a UserError for an unknown value or for
    ``cuda`` where torch sees no GPU (a CPU build of torch, or no driver)."""
    if choice not in DEVICE_CHOICES:
        raise UserError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {choice!r}")
    if choice == "cpu":
        return "cpu"
    available = _cuda_available()
    if choice == "auto":
        return "cuda" if available else "cpu"
    if not available:
        raise UserError(
            "--device cuda, but torch sees no CUDA GPU (a CPU build of torch, or no driver); "
            "pass --device cpu, or install a CUDA build of torch (docs/performance.md, 'On a GPU')"
        )
    return "cuda"


def _cuda_available() -> bool:
    import torch

    return bool(torch.cuda.is_available())


def use_device(name: str) -> None:
    """Make ``name`` (``cpu`` or ``cuda``) this process's compute device; on ``cuda``, with the
    settings that make its kernels deterministic."""
    global _current
    if name not in ("cpu", "cuda"):
        raise ValueError(f"a compute device is cpu or cuda, got {name!r}")
    if name == "cuda":
        resolve_device("cuda")  # one clear line where a worker sees no GPU
        # read by cuBLAS when its first handle is made: set before any CUDA work
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        import torch

        torch.use_deterministic_algorithms(True)
        torch.backends.cudnn.benchmark = False
        torch.backends.cudnn.deterministic = True
        torch.backends.cuda.matmul.allow_tf32 = False
        torch.backends.cudnn.allow_tf32 = False
    _current = name


def current_device() -> str:
    """This process's compute device: ``cpu`` or ``cuda``."""
    return _current


def compute_device() -> Any:
    """This process's compute device as a ``torch.device``."""
    import torch

    return torch.device(_current)


def device_stamp() -> dict[str, Any]:
    """The device's part of every stamp: nothing on the CPU, else the device and the GPU's name."""
    if _current == "cpu":
        return {}
    import torch

    return {"device": _current, "gpu": torch.cuda.get_device_name(0)}


__all__ = ["DEVICE_CHOICES", "compute_device", "current_device", "device_stamp", "resolve_device", "use_device"]
