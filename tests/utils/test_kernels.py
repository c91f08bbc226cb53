"""pin_cpu_kernels pins every library that picks kernels by CPU before it loads, unless the user
chose; importing metadagger loads none of them; the stamp says which kernels a process computes on;
the executors' workers start on the driver's pins."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap

import pytest

from metadagger.utils.kernels import KERNEL_ENV, NATIVE_SWITCH

X86 = pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="the pins apply to x86-64 only")

#: What a fresh process computes on after importing metadagger and pinning, one word per library.
PROBE = textwrap.dedent("""
    import metadagger
    metadagger.pin_cpu_kernels()
    import cv2, numpy, torch
    from numpy._core._multiarray_umath import __cpu_features__
    from metadagger.utils.kernels import kernel_stamp
    torch.ones(2) + 1
    print(torch.backends.cpu.get_cpu_capability(), "numpy-avx512:" + str(__cpu_features__.get("X86_V4", False)),
          "opencv-avx512:" + str("*AVX512-SKX" in (line := cv2.getCPUFeaturesLine()) and "AVX512-SKX?" not in line),
          "stamp:" + str(kernel_stamp()["kernels"] != "native"))
""")


def _probe(script: str = PROBE, **env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in KERNEL_ENV and k != NATIVE_SWITCH}
    done = subprocess.run([sys.executable, "-c", script], env={**clean, **env}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def _has_avx512() -> bool:
    import numpy
    from numpy._core._multiarray_umath import __cpu_features__

    return bool(__cpu_features__.get("AVX512F")) and "X86_V4" in numpy._core._multiarray_umath.__cpu_dispatch__


@X86
def test_importing_metadagger_and_its_command_line_loads_no_numerical_library():
    script = (
        "import sys, metadagger, metadagger.cli.entry; "
        "print(*[m for m in ('numpy', 'torch', 'cv2', 'gymnasium', 'mujoco') if m in sys.modules] or ['none'])"
    )
    assert _probe(script) == ["none"]


@X86
def test_the_pins_take_every_library_off_avx512():
    capability, numpy_avx512, opencv_avx512, stamped = _probe()
    assert capability == "AVX2"
    assert numpy_avx512 == "numpy-avx512:False"
    assert opencv_avx512 == "opencv-avx512:False"
    assert stamped == "stamp:True"


@X86
def test_native_pins_nothing_and_is_stamped_as_such():
    if not _has_avx512():
        pytest.skip("this CPU has no AVX-512: native and pinned kernels are alike")
    capability, numpy_avx512, _, stamped = _probe(**{NATIVE_SWITCH: "native"})
    assert capability == "AVX512"
    assert numpy_avx512 == "numpy-avx512:True"
    assert stamped == "stamp:False"


@X86
def test_a_users_own_setting_wins():
    assert _probe(ATEN_CPU_CAPABILITY="default")[0] == "DEFAULT"


@X86
def test_a_library_loaded_before_the_pin_is_named_in_the_stamp():
    script = (
        "import numpy, metadagger; metadagger.pin_cpu_kernels(); "
        "from metadagger.utils.kernels import kernel_stamp; print(*kernel_stamp()['kernels']['loaded_unpinned'])"
    )
    assert _probe(script) == ["numpy"]
    pinned_first = (
        "import metadagger; metadagger.pin_cpu_kernels(); import numpy; "
        "from metadagger.utils.kernels import kernel_stamp; print('loaded_unpinned' in kernel_stamp()['kernels'])"
    )
    assert _probe(pinned_first) == ["False"]


@X86
def test_pool_workers_start_on_the_pins_when_their_driver_set_none():
    script = textwrap.dedent("""
        import os
        from metadagger.utils.executors import make_executor

        if __name__ == "__main__":
            with make_executor("local", workers=1) as ex:
                print(*ex.imap_unordered(os.getenv, ["NPY_DISABLE_CPU_FEATURES"]), sep="|")
    """)
    assert _probe(script) == KERNEL_ENV["NPY_DISABLE_CPU_FEATURES"].split()


def test_a_ray_worker_gets_the_pins_or_the_native_switch(monkeypatch):
    from metadagger.utils import kernels
    from metadagger.utils.kernels import pin_cpu_kernels, pinned_environment

    monkeypatch.setattr(kernels, "_loaded_unpinned", set())  # this process's record stays as it was

    monkeypatch.setenv(NATIVE_SWITCH, "native")
    assert pinned_environment() == {NATIVE_SWITCH: "native"}
    if platform.machine().lower() in ("x86_64", "amd64"):
        monkeypatch.delenv(NATIVE_SWITCH)
        for name in KERNEL_ENV:  # set, then removed: the test's end restores each as it was
            monkeypatch.setenv(name, "")
            monkeypatch.delenv(name)
        pin_cpu_kernels()
        assert pinned_environment() == KERNEL_ENV


def _scripted_root(x):
    return x.sqrt()


def test_the_vector_math_audit_names_mkl_calls_in_python_and_torchscript_and_nothing_else():
    import torch

    from metadagger.utils.kernels import mkl_vector_math_calls

    x = torch.rand(64, dtype=torch.float64) + 0.5
    assert mkl_vector_math_calls(lambda: (x.exp(), x.clone().log_(), torch.tanh(x), x**0.5)) == [
        "aten::exp",
        "aten::log_",
        "aten::pow",
        "aten::tanh",
    ]
    scripted = torch.jit.script(_scripted_root)
    assert mkl_vector_math_calls(lambda: scripted(x.float())) == ["aten::sqrt"]
    # ATen's own vectorised kernels, which the pins fix: softmax and its log, sigmoid, Adam's fused step
    p = torch.zeros(64)
    fused = torch.optim.Adam([p], lr=0.1, fused=True)
    p.grad = torch.ones(64)
    assert (
        mkl_vector_math_calls(lambda: (x.softmax(0), x.log_softmax(0), x.sigmoid(), x.square(), x**-0.5, fused.step()))
        == []
    )
