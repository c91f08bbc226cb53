"""Connecting to a Ray cluster: its address checked, reached and named in one clear line.

:class:`~metadagger.utils.executors.RayExecutor` and
:func:`~metadagger.utils.executors.check_executor_options` call these before ``ray.init``: Ray
itself keeps retrying an unreachable or wrong address for minutes and reports a head that refuses
this driver's missing token as a failed connection, so each case here fails within seconds with a
message that says what to fix.
"""

from __future__ import annotations

import contextlib
import os
import socket
from pathlib import Path
from typing import Any, Iterator

from metadagger.errors import UserError

__all__ = ["ADDRESS_HINT", "bounded_gcs_wait", "check_reachable", "import_ray", "token_hint"]

# Seconds to wait for a Ray cluster's port to accept a connection: a live head answers in
# milliseconds, while Ray keeps retrying an unreachable one (Ray Client for 30 s, HOST:PORT longer).
_CONNECT_TIMEOUT_S = 3.0
# Ray's setting for how many times (about a second apart) ray.init tries a cluster's GCS: by
# default 20, each failed try logging a warning that no Ray log level silences.
_GCS_WAIT_VAR = "RAY_gcs_server_port_wait_time_s"
_INSTALL_RAY = 'pip install -c constraints.txt -e ".[ray]"'
ADDRESS_HINT = "expected 'ray://HEAD:10001' (Ray Client), 'HEAD:6379' (on a cluster node) or 'auto'"


def token_hint() -> str:
    """A hint when this machine holds a Ray token the driver does not send: a head started by
    ``ray start`` beside ``~/.ray/auth_token`` (which any local Ray instance writes) refuses drivers
    that lack it, and Ray reports that as a failed connection."""
    token = Path.home() / ".ray" / "auth_token"
    if not token.is_file() or os.environ.get("RAY_AUTH_MODE") == "token":
        return ""
    return (
        f"; or, if the cluster uses token authentication (this machine has {token}), "
        "set RAY_AUTH_MODE=token so that the driver sends the token"
    )


def import_ray() -> Any:
    """The ``ray`` module; not installed, a UserError that says how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(f"executor 'ray' needs Ray, which is not installed; install it with: {_INSTALL_RAY}") from None
    return ray


@contextlib.contextmanager
def bounded_gcs_wait(address: str | None) -> Iterator[None]:
    """Connecting to ``address``, let ray.init try the cluster's GCS :data:`_CONNECT_TIMEOUT_S`
    times instead of Ray's 20, so a port that answers but is no Ray head fails with a few of Ray's
    warnings, not twenty; a local instance, or a number the user set, is left alone."""
    if address is None or _GCS_WAIT_VAR in os.environ:
        yield
        return
    os.environ[_GCS_WAIT_VAR] = str(int(_CONNECT_TIMEOUT_S))
    try:
        yield
    finally:
        del os.environ[_GCS_WAIT_VAR]


def check_reachable(address: str | None) -> None:
    """Raise UserError unless ``address`` (``ray://HOST:PORT``, ``HOST:PORT``, or ``"auto"``: the
    cluster Ray finds for it) accepts a TCP connection within a few seconds; ``None`` (a local
    instance) needs no check."""
    if address is None:
        return
    target = _auto_address() if address == "auto" else address
    host, _, port = target.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise UserError(f"bad Ray address {target!r}; {ADDRESS_HINT}")
    found = f" (found for {address!r})" if target != address else ""
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise UserError(
            f"cannot reach a Ray cluster at {target!r}{found} ({exc.strerror or exc}); "
            f"check that its head is running (ray start --head) and the host and port: {ADDRESS_HINT}"
        ) from None
    if not _answers_grpc(f"{host}:{port}"):
        raise UserError(
            f"{target!r}{found} accepts connections but does not answer as a Ray cluster within "
            f"{_CONNECT_TIMEOUT_S:.0f} s; "
            f"check the host and port (a head's GCS port, or its Ray Client port for ray://): {ADDRESS_HINT}"
        )


def _answers_grpc(target: str) -> bool:
    """Whether ``target`` (``HOST:PORT``) completes a gRPC handshake within :data:`_CONNECT_TIMEOUT_S`,
    as a Ray head's GCS and Ray Client server do at once; ray.init would wait minutes on a port
    that accepts connections but never answers. True without grpcio (Ray without its client extra)."""
    try:
        import grpc
    except ImportError:
        return True
    channel = grpc.insecure_channel(target)
    try:
        grpc.channel_ready_future(channel).result(timeout=_CONNECT_TIMEOUT_S)
        return True
    except grpc.FutureTimeoutError:
        return False
    finally:
        channel.close()


def _auto_address() -> str:
    """The cluster ``ray.init(address="auto")`` connects to: ``RAY_ADDRESS``, else one started on
    this node by ``ray start`` (found by Ray's own lookup)."""
    from ray._private.services import canonicalize_bootstrap_address

    try:
        return os.environ.get("RAY_ADDRESS") or canonicalize_bootstrap_address("auto")
    except ConnectionError:
        raise UserError(
            "no Ray cluster found for address 'auto': RAY_ADDRESS is not set and no `ray start` runs on this node; "
            f"start one (ray start --head) or pass its address: {ADDRESS_HINT}"
        ) from None
