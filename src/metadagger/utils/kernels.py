"""One set of CPU kernels on every x86-64 machine, as far as the libraries allow.

Several libraries metadagger computes with pick their kernels by the CPU they run on, and two
kernels of one operation round differently in the last bits, which a training run amplifies: the
quick CarRacing preset gave another MDM table on an Intel AVX-512 machine than on an AMD one.
:func:`pin_cpu_kernels` puts into the environment, for each library, the setting that asks for
kernels every x86-64 CPU of the last decade has (AVX2 and FMA):

=====================  ===========================  ==========================================
library                what it computes here         pin
=====================  ===========================  ==========================================
PyTorch (ATen)         elementwise ops, reductions   ``ATEN_CPU_CAPABILITY=avx2``
oneDNN                 convolutions                  ``ONEDNN_MAX_CPU_ISA=AVX2``
MKL                    torch's matrix products,      ``MKL_CBWR=COMPATIBLE``: the one branch of
                       eigh, solve                   MKL's reproducibility modes documented to
                                                     agree on Intel and non-Intel processors
OpenBLAS (numpy's)     numpy's dot, norm, matmul     ``OPENBLAS_CORETYPE=Haswell``
numpy's SIMD loops     exp, log, sums, sorting       ``NPY_DISABLE_CPU_FEATURES`` = its AVX-512
                                                     targets
OpenCV                 CarRacing's frames            ``OPENCV_CPU_DISABLE=AVX512-SKX``
Mesa llvmpipe          Fetch's frames (EGL, no GPU)  ``LP_NATIVE_VECTOR_WIDTH=256``
=====================  ===========================  ==========================================

ATen, oneDNN and MKL read their setting at their first kernel; OpenBLAS, numpy and OpenCV when
they load. So the pin must come before numpy is imported: the command line pins first thing
(:func:`metadagger.cli.entry.main`), importing :mod:`metadagger` loads no numerical library, and
the executors' workers start with the driver's environment (a Ray worker gets it through its
``runtime_env``). A process that loaded numpy or OpenCV unpinned computes on its machine's own
kernels; :func:`kernel_stamp` records that, so its artifacts are never mixed with pinned ones.

A variable the user set keeps its value; ``METADAGGER_KERNELS=native`` pins nothing (each library
chooses for its CPU: faster on AVX-512 machines, numbers that hold on that machine kind only).
What is still left to the machine (oneDNN's and MKL's blocking by cache size, Mesa's code
generation) is listed in docs/architecture.md, "Determinism".
"""

from __future__ import annotations

import functools
import os
import platform
import sys
from typing import Any, Callable

from metadagger.utils.device import device_stamp

#: The environment that pins each library's kernels (x86-64).
KERNEL_ENV = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "MKL_CBWR": "COMPATIBLE",
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENCV_CPU_DISABLE": "AVX512-SKX",
    "LP_NATIVE_VECTOR_WIDTH": "256",
}

#: The switch that leaves every library to its own choice of kernels.
NATIVE_SWITCH = "METADAGGER_KERNELS"

#: Bumped by every change to metadagger's code that changes a number a stage makes; it is part
#: of every stage's stamp (:func:`kernel_stamp`), so such a change marks finished work stale.
NUMERICS = 4

#: Libraries that read their pin when they load, by module name and variable.
_READ_AT_LOAD = {"numpy": "NPY_DISABLE_CPU_FEATURES", "cv2": "OPENCV_CPU_DISABLE"}

#: The libraries this process loaded before it pinned their kernels (see :func:`pin_cpu_kernels`).
_loaded_unpinned: set[str] = set()


#: ATen operations whose floating-point CPU kernels call MKL's vector math library (ATen's
#: ``cpu/vml.h``). No variable pins those: their bits depend on the CPU (and on ``MKL_CBWR``), so no
#: computation on a run's path may call them (docs/determinism.md, "Kernels no variable pins").
#: ``pow`` joins them at an exponent of 0.5, which ATen computes as ``sqrt``.
MKL_VECTOR_MATH_OPS = frozenset(
    (
        "acos",
        "asin",
        "atan",
        "cos",
        "erf",
        "erfc",
        "erfinv",
        "exp",
        "log",
        "log10",
        "log2",
        "sin",
        "sqrt",
        "tan",
        "tanh",
    )
)


def mkl_vector_math_calls(run: Callable[[], Any]) -> list[str]:
    """The ATen operations of :data:`MKL_VECTOR_MATH_OPS` (in-place forms too, and ``pow`` at an
    exponent of 0.5) that ``run()`` calls, by name, sorted; TorchScript's calls are seen as well.
    Empty: every elementwise kernel it reached is ATen's own, which the pins fix on every x86-64 CPU."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as profiler:
        run()
    found = set()
    for event in profiler.events():
        op = event.name[len("aten::") :].rstrip("_") if event.name.startswith("aten::") else ""
        exponent = (event.concrete_inputs or [None, None])[1] if op == "pow" else None
        if op in MKL_VECTOR_MATH_OPS or exponent == 0.5:
            found.add(event.name)
    return sorted(found)


def _is_x86() -> bool:
    return platform.machine().lower() in ("x86_64", "amd64")


def _native() -> bool:
    return os.environ.get(NATIVE_SWITCH, "").strip().lower() == "native"


def pin_cpu_kernels() -> None:
    """Pin the CPU kernels of every library in :data:`KERNEL_ENV` (x86-64; a no-op elsewhere, or
    with ``METADAGGER_KERNELS=native``). A variable already set keeps its value. Idempotent.

    Call it before numpy, OpenCV or torch load; a library loaded unpinned keeps its machine's
    kernels for the life of the process, and :func:`kernel_stamp` says so.
    """
    if not _is_x86() or _native():
        return
    for module, name in _READ_AT_LOAD.items():
        if module in sys.modules and name not in os.environ:
            _loaded_unpinned.add(module)
    for name, value in KERNEL_ENV.items():
        os.environ.setdefault(name, value)


def kernel_stamp() -> dict[str, Any]:
    """The numerics a stage's artifacts are made with, for its stamp: :data:`NUMERICS`, the
    kernel settings in effect (``native`` where nothing is pinned; the libraries that loaded
    before their pin, if any) and, off the CPU, the compute device (:func:`device_stamp`)."""
    if not _is_x86() or _native():
        return {"numerics": NUMERICS, "kernels": "native", **device_stamp()}
    kernels: dict[str, Any] = {name: os.environ.get(name) for name in KERNEL_ENV}
    if _loaded_unpinned:
        kernels["loaded_unpinned"] = sorted(_loaded_unpinned)
    return {"numerics": NUMERICS, "kernels": kernels, **device_stamp()}


def pinned_environment() -> dict[str, str]:
    """The pins as environment variables for a process started elsewhere (a Ray worker): the
    values in effect here, or the switch that pins nothing."""
    if _native():
        return {NATIVE_SWITCH: "native"}
    return {name: os.environ[name] for name in KERNEL_ENV if name in os.environ}


#: The instruction sets that decide which kernels a library may pick, as /proc/cpuinfo names them.
_ISA_FLAGS = (
    "sse4_2",
    "avx",
    "avx2",
    "fma",
    "avx512f",
    "avx512bw",
    "avx512vl",
    "avx512_vnni",
    "avx512_bf16",
    "amx_tile",
)


@functools.lru_cache(maxsize=1)
def _cpu() -> tuple[str, tuple[str, ...]]:
    """This machine's CPU model and the instruction sets of :data:`_ISA_FLAGS` it has (read once)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name":
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                    break
    except OSError:
        pass
    return model, tuple(f for f in _ISA_FLAGS if f in flags)


def machine_description() -> dict[str, Any]:
    """The CPU a result was made on: model, instruction sets (those that decide kernels), cores,
    and the kernel settings in effect (:func:`kernel_stamp`)."""
    model, instruction_sets = _cpu()
    return {
        "cpu": model,
        "instruction_sets": list(instruction_sets),
        "cores": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        **kernel_stamp(),
    }
