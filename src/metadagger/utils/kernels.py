"""One set of CPU kernels on every x86-64 machine, so that a run gives the same numbers anywhere.

PyTorch and oneDNN pick their CPU kernels by the instruction set of the machine they run on: AVX2
on one machine and AVX-512 on another, whose floating-point sums differ in their last bits. A
training run amplifies that: the CarRacing quick preset's MDM table differs in most of its rows
between the two (docs/architecture.md, "Determinism"). :func:`pin_cpu_kernels` asks both for their
AVX2 kernels, which every x86-64 CPU of the last decade has; a user who sets either variable
keeps their value (``ATEN_CPU_CAPABILITY=default`` restores the machine's own choice).

Importing metadagger does not pin them: the command line does, first thing
(:func:`metadagger.cli.entry.main`), as do the pipeline's entry points (``reproduce``,
``init_run``, ``load_run``), the local pool's workers and every Ray task; a Python program calls
``metadagger.pin_cpu_kernels()`` itself, before its first tensor operation.
"""

from __future__ import annotations

import os
import platform

#: The environment that selects the AVX2 kernels of ATen and of oneDNN.
KERNEL_ENV = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2"}


def pin_cpu_kernels() -> None:
    """Select the AVX2 kernels on x86-64 unless the environment already chooses (a no-op elsewhere).

    Both libraries read the variables when they first run a kernel, so this must run before the
    process's first tensor operation (importing torch is fine; running a kernel is not): the
    command line, the pipeline's entry points and the executors' workers call it, and a Python
    program that computes with tensors before calling those must call it first. Idempotent.
    """
    if platform.machine().lower() in ("x86_64", "amd64"):
        for name, value in KERNEL_ENV.items():
            os.environ.setdefault(name, value)
