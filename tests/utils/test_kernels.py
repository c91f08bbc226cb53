"""Importing metadagger selects the AVX2 kernels on x86-64, unless the environment already chooses."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

PROBE = "import metadagger, torch, os; torch.ones(2) + 1; print(torch.backends.cpu.get_cpu_capability(), os.environ['ONEDNN_MAX_CPU_ISA'])"


def _probe(**env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA")}
    return subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True, check=True).stdout.split()


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="the pin applies to x86-64 only")
def test_import_pins_the_avx2_kernels_and_a_users_choice_wins():
    import torch

    if torch.backends.cpu.get_cpu_capability() in ("DEFAULT", "NO AVX"):
        pytest.skip("this CPU has no AVX2 kernels")
    assert _probe() == ["AVX2", "AVX2"]
    assert _probe(ATEN_CPU_CAPABILITY="default", ONEDNN_MAX_CPU_ISA="ALL")[1] == "ALL"
