"""The executor: local process pool and Ray give the same results; errors name the item."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from metadagger.errors import CheckpointError, UserError
from metadagger.utils import executors, ray_cluster
from metadagger.utils.executors import Executor, LocalExecutor, WorkerError, check_executor_options, make_executor

ITEMS = list(range(12))
GCS_WAIT = "RAY_gcs_server_port_wait_time_s"


def _pid(_: object) -> int:
    return os.getpid()


def _square(x: int) -> int:
    return x * x


def _fail_on_seven(x: int) -> int:
    if x == 7:
        raise ValueError(f"cannot handle {x}")
    return x


@dataclass(frozen=True)
class _Job:
    seed: int


def _corrupt_file_on_seed_1003(job: _Job) -> int:
    if job.seed == 1003:
        raise CheckpointError("mapper checkpoint is corrupt or not a safetensors file: m.safetensors")
    return job.seed


def _slow_on_zero(x: int) -> int:
    time.sleep(1.0 if x == 0 else 0.0)
    return x


def _torch_threads(_: int) -> int:
    import torch

    return torch.get_num_threads()


@pytest.fixture(scope="module")
def local() -> Iterator[LocalExecutor]:
    # One pool for the module: the first pool of a process starts in seconds (workers import torch).
    with make_executor("local", workers=2) as ex:
        yield ex


def test_local_maps_every_item(local: LocalExecutor) -> None:
    assert sorted(local.imap_unordered(_square, ITEMS)) == [x * x for x in ITEMS]


def test_local_consumes_a_lazy_iterable_longer_than_the_window(local: LocalExecutor) -> None:
    n = 3 * local.workers * 2 + 1
    assert sorted(local.imap_unordered(_square, (x for x in range(n)))) == [x * x for x in range(n)]


def test_local_yields_results_as_they_finish(local: LocalExecutor) -> None:
    assert list(local.imap_unordered(_slow_on_zero, [0, 1])) == [1, 0]


def test_local_workers_use_one_torch_thread(local: LocalExecutor) -> None:
    assert set(local.imap_unordered(_torch_threads, range(4))) == {1}


def test_worker_exception_names_the_item_and_closes() -> None:
    with make_executor("local", workers=2) as ex:
        with pytest.raises(WorkerError, match=r"item 7: ValueError: cannot handle 7") as info:
            list(ex.imap_unordered(_fail_on_seven, ITEMS))
        assert info.value.item == 7
        assert isinstance(info.value.__cause__, ValueError)
        with pytest.raises(UserError, match="closed"):
            ex.imap_unordered(_square, ITEMS)


def test_a_user_error_in_a_worker_stays_a_user_error() -> None:
    jobs = [_Job(seed) for seed in range(1000, 1006)]
    with (
        make_executor("local", workers=2) as ex,
        pytest.raises(
            UserError, match=r"^seed 1003: mapper checkpoint is corrupt or not a safetensors file: m\.safetensors$"
        ) as info,
    ):
        list(ex.imap_unordered(_corrupt_file_on_seed_1003, jobs))
    assert not isinstance(info.value, WorkerError)
    assert isinstance(info.value.__cause__, CheckpointError)


def test_inline_runs_each_job_here_in_order_and_names_a_failing_item() -> None:
    with make_executor("inline") as inline:
        assert list(inline.imap_unordered(_pid, [None])) == [os.getpid()]  # in this process
        assert list(inline.imap_unordered(_square, ITEMS)) == [x * x for x in ITEMS]
    with make_executor("inline") as inline, pytest.raises(WorkerError, match="7"):
        list(inline.imap_unordered(_fail_on_seven, ITEMS))
    with pytest.raises(UserError, match="executor 'inline' runs one job at a time"):
        make_executor("inline", workers=2)


def test_unpicklable_function_is_a_user_error(local: LocalExecutor) -> None:
    with pytest.raises(UserError, match="top level of a module"):
        local.imap_unordered(lambda x: x, ITEMS)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "dask"}, "unknown executor 'dask'; expected 'local', 'ray' or 'inline'"),
        ({"kind": "local", "workers": 0}, "workers must be a positive integer, got 0"),
        ({"kind": "ray", "workers": -1}, "workers must be a positive integer, got -1"),
        ({"kind": "local", "address": "auto"}, "only applies to executor 'ray'"),
        ({"kind": "inline", "address": "auto"}, "only applies to executor 'ray'"),
    ],
)
def test_bad_arguments_are_user_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(UserError, match=match):
        check_executor_options(kwargs.get("kind"), kwargs.get("workers"), kwargs.get("address"))
    with pytest.raises(UserError, match=match):
        make_executor(**kwargs)


def test_ray_not_installed_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    with pytest.raises(UserError, match=r'install it with: pip install -c constraints\.txt -e "\.\[ray\]"$'):
        make_executor("ray")


@pytest.mark.parametrize("scheme", ["ray://", ""], ids=["ray-client", "host-port"])
@pytest.mark.parametrize(
    "port, message",
    [
        ("closed_port", "cannot reach a Ray cluster at '{address}' .*'ray://HEAD:10001'"),
        (
            "silent_port",
            "'{address}' accepts connections but does not answer as a Ray cluster within 3 s.*'ray://HEAD:10001'",
        ),
    ],
    ids=["refused", "never-answers"],
)
def test_an_unreachable_ray_address_fails_within_seconds(
    request: pytest.FixtureRequest, port: str, message: str, scheme: str
) -> None:
    pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    address = f"{scheme}127.0.0.1:{request.getfixturevalue(port)}"
    start = time.monotonic()
    with pytest.raises(UserError, match=message.format(address=address)):
        make_executor("ray", address=address)
    assert time.monotonic() - start < 15


def test_auto_is_checked_before_any_work_like_any_address(closed_port: int, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    from ray._private import services

    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{closed_port}")  # what "auto" connects to first
    with pytest.raises(
        UserError, match=f"cannot reach a Ray cluster at '127.0.0.1:{closed_port}' \\(found for 'auto'\\)"
    ):
        check_executor_options("ray", None, "auto")
    monkeypatch.delenv("RAY_ADDRESS")

    def no_cluster(address: str) -> str:
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(services, "canonicalize_bootstrap_address", no_cluster)
    with pytest.raises(
        UserError, match="no Ray cluster found for address 'auto': RAY_ADDRESS is not set and no `ray start`"
    ):
        check_executor_options("ray", None, "auto")


def test_connecting_bounds_how_long_ray_tries_the_cluster(monkeypatch: pytest.MonkeyPatch) -> None:
    ray = pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    seen = []

    def init(**kwargs) -> None:  # a port that answers but is no Ray head: Ray's retries end in ConnectionError
        seen.append(os.environ.get(GCS_WAIT))
        raise ConnectionError(f"Failed to connect to Ray cluster at {kwargs['address']}")

    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray_cluster, "_answers_grpc", lambda target: True)  # e.g. a gRPC service that is not Ray's
    monkeypatch.delenv(GCS_WAIT, raising=False)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        address = f"127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises(UserError, match=f"^cannot connect to Ray at '{address}' \\(Failed to connect"):
            make_executor("ray", address=address)
        assert seen == ["3"] and GCS_WAIT not in os.environ  # 3 tries of about a second, not Ray's 20
        monkeypatch.setenv(GCS_WAIT, "40")  # a wait the user chose is kept
        with pytest.raises(UserError):
            make_executor("ray", address=address)
    assert seen == ["3", "40"] and os.environ[GCS_WAIT] == "40"


def test_a_refused_connection_names_the_token_of_this_machine(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    ray = pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')

    def init(**kwargs) -> None:  # how Ray reports a head that refuses this driver's (missing) token
        raise ConnectionError(f"Failed to connect to Ray cluster at {kwargs['address']}")

    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(executors, "check_reachable", lambda address: None)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    with pytest.raises(UserError) as error:
        make_executor("ray", address="127.0.0.1:6379")
    assert "token" not in str(error.value)  # no token here: nothing to say about one
    (tmp_path / ".ray").mkdir()
    (tmp_path / ".ray" / "auth_token").write_text("x" * 64)
    with pytest.raises(
        UserError, match=r"^cannot connect to Ray at '127\.0\.0\.1:6379' .*set RAY_AUTH_MODE=token[^\n]*$"
    ):
        make_executor("ray", address="127.0.0.1:6379")
    monkeypatch.setenv("RAY_AUTH_MODE", "token")
    with pytest.raises(UserError) as error:
        make_executor("ray", address="127.0.0.1:6379")
    assert "RAY_AUTH_MODE" not in str(error.value)


def test_a_ray_address_without_a_port_is_a_user_error() -> None:
    pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    with pytest.raises(UserError, match="bad Ray address 'ray://head'; expected 'ray://HEAD:10001'"):
        check_executor_options("ray", None, "ray://head")


_DRIVER = textwrap.dedent(
    """
    import os, signal, sys, time
    from metadagger.utils.executors import make_executor

    # A shell's background job starts with SIGINT ignored, and Python then raises no
    # KeyboardInterrupt; restore its handler so the test does not depend on how it was launched.
    signal.signal(signal.SIGINT, signal.default_int_handler)

    def work(item):
        # The worker's pid, for the test to check it is gone; one write() so lines never interleave.
        os.write(1, f"{os.getpid()}\\n".encode())
        time.sleep(60)

    if __name__ == "__main__":
        with make_executor("local", workers=2) as ex:
            for _ in ex.imap_unordered(work, range(4)):
                pass
    """
)


def _read_line(proc: subprocess.Popen) -> str:
    line = proc.stdout.readline()
    assert line, f"driver exited early: {proc.stderr.read()}"
    return line


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie awaiting its reaper counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc (Linux)")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["ctrl-c", "sigkill"])
def test_stopping_the_driver_stops_its_workers_promptly(tmp_path: Path, sig: signal.Signals) -> None:
    script = tmp_path / "driver.py"
    script.write_text(_DRIVER)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        worker_pids = [int(_read_line(proc)) for _ in range(2)]  # both workers are busy
        start = time.monotonic()
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=15)
        while any(map(_running, worker_pids)) and time.monotonic() - start < 10:
            time.sleep(0.05)
        elapsed = time.monotonic() - start
    finally:
        proc.kill()
    assert proc.returncode != 0
    if sig == signal.SIGINT:
        assert "KeyboardInterrupt" in stderr
    assert not any(map(_running, worker_pids)), f"workers still running {elapsed:.1f} s after the driver got {sig.name}"


@pytest.fixture(scope="module")
def ray_executor() -> Iterator[Executor]:
    ray = pytest.importorskip("ray", reason='Ray is optional: pip install -c constraints.txt -e ".[ray]"')
    # Ray workers import a function's module by name, and this test module is not installed:
    # ship its functions by value instead.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    # One local instance for the module (start-up takes seconds); the executor owns it.
    with make_executor("ray", workers=2) as ex:
        yield ex
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert not ray.is_initialized(), "the executor should shut down the Ray instance it started"


def test_ray_gives_the_same_results_as_local(ray_executor: Executor, local: LocalExecutor) -> None:
    assert sorted(ray_executor.imap_unordered(_square, ITEMS)) == sorted(local.imap_unordered(_square, ITEMS))
    assert set(ray_executor.imap_unordered(_torch_threads, range(4))) == {1}


# Last Ray test: a failure closes the executor (and the Ray instance it started).
def test_ray_worker_exception_names_the_item(ray_executor: Executor) -> None:
    with pytest.raises(WorkerError, match=r"item 7: ValueError: cannot handle 7") as info:
        list(ray_executor.imap_unordered(_fail_on_seven, ITEMS))
    assert isinstance(info.value.__cause__, ValueError)
