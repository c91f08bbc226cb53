"""pin_cpu_kernels selects the AVX2 kernels on x86-64, unless the environment already chooses; the
executors' workers run on them whether or not their driver pinned them."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap

import pytest

PROBE = ("import metadagger, torch, os; metadagger.pin_cpu_kernels(); torch.ones(2) + 1; "
         "print(torch.backends.cpu.get_cpu_capability(), os.environ['ONEDNN_MAX_CPU_ISA'])")
X86 = pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="the pin applies to x86-64 only")


def _probe(script: str = PROBE, **env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA")}
    return subprocess.run([sys.executable, "-c", script], env={**clean, **env}, capture_output=True, text=True, check=True).stdout.split()


@X86
def test_the_pin_selects_the_avx2_kernels_and_a_users_choice_wins():
    import torch

    if torch.backends.cpu.get_cpu_capability() in ("DEFAULT", "NO AVX"):
        pytest.skip("this CPU has no AVX2 kernels")
    assert _probe() == ["AVX2", "AVX2"]
    assert _probe(ATEN_CPU_CAPABILITY="default", ONEDNN_MAX_CPU_ISA="ALL")[1] == "ALL"


@X86
def test_pool_workers_pin_the_kernels_when_their_driver_did_not():
    script = textwrap.dedent("""
        import os
        from metadagger.utils.executors import make_executor

        if __name__ == "__main__":
            with make_executor("local", workers=1) as ex:
                print(os.environ.get("ATEN_CPU_CAPABILITY"), *ex.imap_unordered(os.getenv, ["ATEN_CPU_CAPABILITY"]))
    """)
    assert _probe(script) == ["None", "avx2"]
