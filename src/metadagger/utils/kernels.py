"""One set of CPU kernels on every x86-64 machine, so that a run gives the same numbers anywhere.

PyTorch and oneDNN pick their CPU kernels by the instruction set of the machine they run on: AVX2
on one machine and AVX-512 on another, whose floating-point sums differ in their last bits. A
training run amplifies that: the CarRacing quick preset's MDM table differs in most of its rows
between the two (docs/architecture.md, "Determinism"). :func:`pin_cpu_kernels` asks both for their
AVX2 kernels, which every x86-64 CPU of the last decade has; a user who sets either variable
keeps their value (``ATEN_CPU_CAPABILITY=default`` restores the machine's own choice).
"""

from __future__ import annotations

import os
import platform

#: The environment that selects the AVX2 kernels of ATen and of oneDNN.
KERNEL_ENV = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2"}


def pin_cpu_kernels() -> None:
    """Select the AVX2 kernels on x86-64 unless the environment already chooses (a no-op elsewhere).

    Both libraries read the variables when they first run a kernel, so this must run before any
    tensor operation: importing :mod:`metadagger` does it, and every worker process imports it.
    """
    if platform.machine().lower() in ("x86_64", "amd64"):
        for name, value in KERNEL_ENV.items():
            os.environ.setdefault(name, value)
