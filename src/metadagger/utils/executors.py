"""One executor interface for per-seed work: a local process pool or Ray tasks.

Pair collection and evaluation are embarrassingly parallel over seeds. The driver maps a top-level
function over items with :meth:`Executor.imap_unordered` and receives each result as soon as it is
ready, so it can write that seed's artifact at once (only the driver writes artifacts; a killed
run then loses at most the seeds in flight).

Example:
    >>> with make_executor("local", workers=4) as ex:          # doctest: +SKIP
    ...     for result in ex.imap_unordered(collect_pair, seeds):
    ...         store.write(...)
"""

from __future__ import annotations

import abc
import multiprocessing
import os
import pickle
import signal
import threading
from concurrent import futures
from typing import Any, Callable, Generic, Iterable, Iterator, TypeVar

import torch

from metadagger.errors import UserError
from metadagger.utils.device import current_device, use_device
from metadagger.utils.kernels import pin_cpu_kernels, pinned_environment
from metadagger.utils.ray_cluster import ADDRESS_HINT, bounded_gcs_wait, check_reachable, import_ray, token_hint

__all__ = [
    "Executor",
    "LocalExecutor",
    "RayExecutor",
    "WorkerError",
    "check_executor_options",
    "default_workers",
    "in_order",
    "make_executor",
]

T = TypeVar("T")
R = TypeVar("R")
H = TypeVar("H")  # an in-flight handle: a Future or a Ray ObjectRef

# Items kept in flight per worker: enough to keep every worker busy while the driver writes a
# result, few enough that an interrupt has little queued work to cancel.
_IN_FLIGHT_PER_WORKER = 2


class WorkerError(RuntimeError):
    """A work function raised; the message names the failing item and the original error.

    The original exception (with the worker's traceback where the backend provides it) is the
    ``__cause__``; ``item`` holds the item that failed.
    """

    def __init__(self, item: Any, cause: BaseException) -> None:
        super().__init__(f"work failed on {_describe(item)}: {type(cause).__name__}: {cause}")
        self.item = item


def _describe(item: Any) -> str:
    """How messages name an item: by its seed for per-seed jobs, else by its repr."""
    seed = getattr(item, "seed", None)
    return f"item {item!r}" if seed is None else f"seed {seed}"


def in_order(results: Iterable[R], keys: Iterable[Any], key: Callable[[R], Any]) -> Iterator[R]:
    """``results`` (from :meth:`Executor.imap_unordered`, in any order) in the order of ``keys``:
    each is yielded as soon as every one before it has arrived, so whatever consumes them (a
    dataset, a study) is the same whatever the worker count."""
    waiting: dict[Any, R] = {}
    order = iter(keys)
    expected = next(order, None)
    for result in results:
        waiting[key(result)] = result
        while expected in waiting:
            yield waiting.pop(expected)
            expected = next(order, None)


def default_workers() -> int:
    """Return the number of cores this process may run on (its CPU affinity where known)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def _limit_threads() -> None:
    # One torch thread per worker: N workers x N intra-op threads would oversubscribe the cores.
    torch.set_num_threads(1)


def _init_pool_worker(device: str = "cpu") -> None:
    _limit_threads()
    use_device(device)  # the driver's compute device (utils/device.py)
    # A terminal Ctrl-C reaches the whole process group; only the driver should react (it
    # terminates the pool), so workers do not die mid-task with tracebacks of their own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A pool worker holds both ends of its task queue, so if the driver is SIGKILLed it would
    # wait for tasks forever; watch the driver and exit with it instead.
    driver = multiprocessing.parent_process()
    if driver is not None:
        threading.Thread(target=_exit_with, args=(driver,), name="metadagger-driver-watch", daemon=True).start()


def _exit_with(driver: multiprocessing.process.BaseProcess) -> None:
    driver.join()  # returns once the driver's end of the launch pipe closes, i.e. it has exited
    os._exit(1)


class Executor(abc.ABC, Generic[H]):
    """Maps a function over items in parallel; use as a context manager or call :meth:`close`.

    Leaving the ``with`` block on an exception (a :class:`WorkerError`, a ``KeyboardInterrupt``)
    stops in-flight work at once instead of waiting for it. A failed or abandoned
    :meth:`imap_unordered` likewise stops its in-flight work and closes the executor.
    """

    def __init__(self, *, workers: int) -> None:
        self.workers = workers
        self._closed = False

    def imap_unordered(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        """Yield ``fn(item)`` for every item, in the order the results finish.

        Args:
            fn: a top-level (picklable) function of one item; it runs in a worker process.
            items: the items, consumed lazily; at most ``2 * workers`` are in flight at once.

        Raises:
            UserError: the executor is closed, or ``fn`` cannot be pickled (raised at the call);
                or ``fn`` raised a UserError (its message, prefixed with the item).
            WorkerError: ``fn`` raised any other exception on an item (named in the message).
            Either way the remaining work stops.
        """
        if self._closed:
            raise UserError(f"{type(self).__name__} is closed; create a new one with make_executor()")
        # The same contract for every backend (Ray could ship a lambda, a process pool cannot),
        # so code that runs on one executor runs on the other.
        _check_picklable(fn)
        return self._iterate(fn, iter(items))

    def _iterate(self, fn: Callable[[T], R], source: Iterator[T]) -> Iterator[R]:
        pending: dict[H, T] = {}
        finished = False
        try:
            while True:
                for item in source:
                    pending[self._submit(fn, item)] = item
                    if len(pending) >= self.workers * _IN_FLIGHT_PER_WORKER:
                        break
                if not pending:
                    finished = True
                    return
                for handle in self._wait_any(list(pending)):
                    item = pending.pop(handle)
                    try:
                        result = self._result(handle)
                    except UserError as exc:
                        # the user's mistake (a corrupt file, a bad shape): their one-line message
                        raise UserError(f"{_describe(item)}: {exc}") from exc
                    except Exception as exc:
                        raise WorkerError(item, exc) from exc
                    yield result
        finally:
            # Not finished: an error is propagating or the caller stopped early, so nobody will
            # read the pending results; stop them and close, the same on every backend.
            if not finished:
                self._close(cancel=True, in_flight=list(pending))

    def close(self, *, cancel: bool = False) -> None:
        """Release the workers; idempotent.

        Args:
            cancel: stop running work instead of waiting for it (used on errors and Ctrl-C).
        """
        self._close(cancel=cancel, in_flight=[])

    def _close(self, *, cancel: bool, in_flight: list[H]) -> None:
        if not self._closed:
            self._closed = True
            self._shutdown(cancel=cancel, in_flight=in_flight)

    def __enter__(self) -> Executor[H]:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        self.close(cancel=exc_type is not None)

    @abc.abstractmethod
    def _submit(self, fn: Callable[[T], R], item: T) -> H:
        """Start ``fn(item)`` and return its handle."""

    @abc.abstractmethod
    def _wait_any(self, handles: list[H]) -> list[H]:
        """Block until at least one handle is finished; return the finished ones."""

    @abc.abstractmethod
    def _result(self, handle: H) -> Any:
        """Return a finished handle's result or raise its exception."""

    @abc.abstractmethod
    def _shutdown(self, *, cancel: bool, in_flight: list[H]) -> None:
        """Release the workers; with ``cancel``, stop running work (``in_flight``) first."""


class _Deferred:
    """A job of :class:`InlineExecutor`, run when its result is read (hashed by identity)."""

    def __init__(self, fn: Callable[[Any], Any], item: Any) -> None:
        self.fn, self.item = fn, item


class InlineExecutor(Executor[_Deferred]):
    """Each job in this process, one at a time, when its result is read: a profiler or a timer
    sees the work itself, with no pool around it."""

    def __init__(self) -> None:
        super().__init__(workers=1)

    def _submit(self, fn: Callable[[T], R], item: T) -> _Deferred:
        return _Deferred(fn, item)

    def _wait_any(self, handles: list[_Deferred]) -> list[_Deferred]:
        return handles[:1]

    def _result(self, handle: _Deferred) -> Any:
        return handle.fn(handle.item)

    def _shutdown(self, *, cancel: bool, in_flight: list[_Deferred]) -> None:
        pass


def _mp_context() -> multiprocessing.context.BaseContext:
    # Never "fork": forking a process that runs torch threads can deadlock the child. Workers
    # fork from a forkserver that has imported torch once, so after the first pool of a process
    # a pool starts in milliseconds instead of seconds; "spawn" where there is no forkserver.
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    # "__main__" keeps functions of the driver script loadable in the workers (the default).
    context.set_forkserver_preload(["__main__", __name__])
    return context


class LocalExecutor(Executor[futures.Future]):
    """A process pool on this machine (forkserver or spawn workers: safe with torch)."""

    def __init__(self, *, workers: int) -> None:
        super().__init__(workers=workers)
        # The workers (and the forkserver they fork from) start with this environment and load
        # numpy before any code of theirs runs: the pins must be in it now.
        pin_cpu_kernels()
        self._pool = futures.ProcessPoolExecutor(
            max_workers=workers,
            mp_context=_mp_context(),
            initializer=_init_pool_worker,
            initargs=(current_device(),),
        )

    def _submit(self, fn: Callable[[T], R], item: T) -> futures.Future:
        return self._pool.submit(fn, item)

    def _wait_any(self, handles: list[futures.Future]) -> list[futures.Future]:
        done, _ = futures.wait(handles, return_when=futures.FIRST_COMPLETED)
        return list(done)

    def _result(self, handle: futures.Future) -> Any:
        return handle.result()

    def _shutdown(self, *, cancel: bool, in_flight: list[futures.Future]) -> None:
        if not cancel:
            self._pool.shutdown(wait=True)
            return
        # A running future cannot be cancelled, only its process stopped, which stops them all.
        # ProcessPoolExecutor has no public way to stop running workers before Python 3.14
        # (terminate_workers); _processes is the pid -> Process map it keeps.
        processes = list((self._pool._processes or {}).values())  # noqa: SLF001
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.terminate()
        for process in processes:
            process.join(timeout=5)
        # The pool's manager thread now sees dead workers and frees its queues; waiting for it
        # avoids "leaked semaphore" warnings at exit.
        self._pool.shutdown(wait=True)


def _check_picklable(fn: Callable[..., Any]) -> None:
    try:
        pickle.dumps(fn)
    except Exception as exc:
        raise UserError(
            f"work function {fn!r} cannot be sent to a worker process ({type(exc).__name__}: {exc}); "
            "pass a function defined at the top level of a module (not a lambda or a nested function)"
        ) from None


def _run_ray_task(fn: Callable[[T], R], item: T) -> R:
    _limit_threads()
    return fn(item)


class RayExecutor(Executor[Any]):
    """Ray tasks (one CPU each) on an existing cluster or a local instance.

    If Ray is already initialised in this process, that instance is used and left running on
    close; otherwise this executor starts (or connects to) one and shuts it down on close.
    Workers import the work function's module by name, so on a cluster metadagger (and any
    module the function lives in) must be installed on the nodes or shipped with a Ray
    ``runtime_env``; functions of the driver script itself are shipped by value.
    """

    def __init__(self, *, workers: int | None, address: str | None) -> None:
        if current_device() != "cpu":
            raise UserError(
                f"executor 'ray' computes on CPUs, but this run's device is {current_device()}; "
                "use --executor local on the GPU's machine, or a run made with --device cpu"
            )
        ray = import_ray()
        self._ray = ray
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            check_reachable(address)
            # num_cpus may only be given when starting a local instance, not when connecting.
            num_cpus = workers if address is None else None
            try:
                with bounded_gcs_wait(address):
                    ray.init(address=address, num_cpus=num_cpus, include_dashboard=False)
            except ConnectionError as exc:  # e.g. "auto" with no cluster running
                raise UserError(f"cannot connect to Ray at {address!r} ({exc}); {ADDRESS_HINT}{token_hint()}") from None
        if workers is None:
            workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        super().__init__(workers=workers)
        # a worker on another node does not inherit the driver's environment: the kernel pins go
        # with each task, into the worker process's environment before it loads numpy
        self._task = ray.remote(num_cpus=1, runtime_env={"env_vars": pinned_environment()})(_run_ray_task)
        self._fn_ref: tuple[Callable[..., Any], Any] | None = None

    def _submit(self, fn: Callable[[T], R], item: T) -> Any:
        # Put the function in the object store once instead of serialising it with every task.
        if self._fn_ref is None or self._fn_ref[0] is not fn:
            self._fn_ref = (fn, self._ray.put(fn))
        return self._task.remote(self._fn_ref[1], item)

    def _wait_any(self, handles: list[Any]) -> list[Any]:
        done, _ = self._ray.wait(handles, num_returns=1)
        return done

    def _result(self, handle: Any) -> Any:
        try:
            return self._ray.get(handle)
        except self._ray.exceptions.RayTaskError as exc:
            # The user's own exception, chained to Ray's error that carries the worker traceback.
            raise exc.cause from exc

    def _shutdown(self, *, cancel: bool, in_flight: list[Any]) -> None:
        # Closing the connection this executor opened ends its job, and Ray then stops the job's
        # tasks. Under a connection the caller opened, the tasks still running are cancelled; one
        # that finished meanwhile is left alone, since cancelling a task as it completes can abort
        # the driver (a known Ray race, "Tried to complete task that was not pending", seen here
        # after a worker's error).
        if not self._owns_ray and in_flight:
            _, running = self._ray.wait(in_flight, num_returns=len(in_flight), timeout=0)
            for handle in running:
                self._ray.cancel(handle, force=True)
        self._fn_ref = None
        if self._owns_ray:
            self._ray.shutdown()


def check_executor_options(kind: str, workers: int | None, address: str | None) -> None:
    """Raise UserError for options no executor of ``kind`` accepts (see :func:`make_executor`).

    For ``"ray"`` it also checks that Ray is installed and that ``address`` answers, so a command
    fails at once instead of after its first stage.
    """
    if kind not in ("local", "ray", "inline"):
        raise UserError(f"unknown executor {kind!r}; expected 'local', 'ray' or 'inline'")
    if kind == "inline" and workers not in (None, 1):
        raise UserError(
            f"executor 'inline' runs one job at a time in this process, got workers={workers!r}; drop --workers"
        )
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise UserError(f"workers must be a positive integer, got {workers!r}; pass e.g. --workers 4 or leave it unset")
    if kind != "ray" and address is not None:
        raise UserError(f"address {address!r} only applies to executor 'ray'; use --executor ray or drop the address")
    if kind == "ray":
        import_ray()
        check_reachable(address)


def make_executor(kind: str = "local", *, workers: int | None = None, address: str | None = None) -> Executor:
    """Create an executor.

    Args:
        kind: ``"local"`` (a process pool on this machine), ``"ray"`` (Ray tasks) or ``"inline"``
            (each job in this process, one at a time: for profiling and timing).
        workers: parallel workers; default: this machine's cores ("local") or the Ray cluster's
            CPUs ("ray"). For a local Ray instance it is also the number of CPUs it gets.
        address: Ray cluster address (e.g. ``"ray://head:10001"`` or ``"auto"``); ``None`` starts
            a local Ray instance. Only valid with ``kind="ray"``.

    Raises:
        UserError: see :func:`check_executor_options`; or Ray refuses the connection.
    """
    check_executor_options(kind, workers, address)
    if kind == "local":
        return LocalExecutor(workers=workers or default_workers())
    if kind == "inline":
        return InlineExecutor()
    return RayExecutor(workers=workers, address=address)
