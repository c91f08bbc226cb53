"""The same bits on another CPU, on this machine: ``metadagger bench ops`` under QEMU's user-mode
emulation of a CPU of the other vendor (Debian's qemu-user), which answers CPUID as that model does,
so MKL, oneDNN and ATen pick the kernels they would pick there. An op whose bits depend on the CPU
(MKL's vector math, for one) differs here without a second machine (docs/determinism.md)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from metadagger.utils.kernels import machine_description

QEMU = shutil.which("qemu-x86_64")


def _other_vendor_model() -> str:
    """An emulated CPU of the other vendor than this machine's (AVX2 and FMA, as the pins ask)."""
    return "Skylake-Client-v4" if "AMD" in machine_description()["cpu"] else "EPYC-v3"


@pytest.mark.skipif(
    QEMU is None, reason="qemu-user is not installed (`apt-get install qemu-user`; .ci/run installs it)"
)
def test_every_fingerprinted_op_gives_this_cpus_bits_on_a_cpu_of_the_other_vendor(tmp_path):
    env = {**os.environ, "MUJOCO_GL": "egl"}
    command = [sys.executable, "-m", "metadagger.cli", "bench", "ops"]
    native = tmp_path / "native.json"
    done = subprocess.run([*command, "--out", str(native)], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    model = _other_vendor_model()
    emulated = tmp_path / f"{model}.json"
    done = subprocess.run(
        [QEMU, "-cpu", model, *command, "--out", str(emulated), "--compare", str(native)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    compared = json.loads(emulated.read_text())["compared"]
    assert compared["differ"] == [], f"under {model}: {compared['differ']}"
    assert compared["same"] == len(json.loads(native.read_text())["ops"])
