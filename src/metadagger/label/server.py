"""The labelling page's web server: on the loopback address only, every request carrying the session's token.

A small Starlette app served by uvicorn in a thread of the command. It serves the package's page
(``page.html``, ``page.js``) and, from memory, the frames of the state asked now and its
neighbours and a clip of the learner's last rollout (:class:`~metadagger.label.desk.Desk`); it
reads no file of the run folder or anywhere else. A request without the random token of the
printed URL, or naming another host than the loopback one, is refused.
"""

from __future__ import annotations

import json
import secrets
import socket
import threading
import time
from importlib import resources
from types import TracebackType
from typing import Any, Awaitable, Callable
from urllib.parse import parse_qs

import cv2
import numpy as np

from metadagger.errors import UserError
from metadagger.label.desk import Desk
from metadagger.label.forms import Refused

#: The address the page is served on: this machine alone.
LOOPBACK = "127.0.0.1"
#: Where the token stands in the page's HTML.
TOKEN_MARK = "__TOKEN__"


def require_server() -> tuple[Any, Any]:
    """Starlette and uvicorn, or a :class:`UserError` saying how to install them."""
    try:
        import starlette
        import uvicorn
    except ImportError:
        raise UserError(
            "metadagger label needs starlette and uvicorn; install them with "
            "`pip install -e '.[label]' -c constraints.txt` (or `bash scripts/setup.sh label`)"
        ) from None
    return starlette, uvicorn


def png(image: np.ndarray) -> bytes:
    """An observation (``H x W x C`` uint8, RGB or grey) as PNG bytes."""
    image = np.ascontiguousarray(image)
    if image.ndim == 3 and image.shape[2] >= 3:
        image = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"cannot encode an image of shape {image.shape} as PNG")
    return data.tobytes()


def make_app(desk: Desk, token: str) -> Any:
    """The page's ASGI app: every route answers only a request with ``token``, on the loopback host."""
    require_server()
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.middleware import Middleware
    from starlette.middleware.trustedhost import TrustedHostMiddleware
    from starlette.requests import Request
    from starlette.responses import JSONResponse, Response
    from starlette.routing import Route

    page = resources.files("metadagger.label")
    html = page.joinpath("page.html").read_text().replace(TOKEN_MARK, token)
    script = page.joinpath("page.js").read_text()
    fresh = {"Cache-Control": "no-store"}

    def refused(exc: Refused) -> JSONResponse:
        return JSONResponse({"error": str(exc)}, status_code=exc.status, headers=fresh)

    def guarded(work: Callable[[Request], Awaitable[Response]]) -> Callable[[Request], Awaitable[Response]]:
        async def endpoint(request: Request) -> Response:
            try:
                return await work(request)
            except Refused as exc:
                return refused(exc)

        return endpoint

    async def index(request: Request) -> Response:
        return Response(html, media_type="text/html; charset=utf-8", headers=fresh)

    async def js(request: Request) -> Response:
        return Response(script, media_type="text/javascript; charset=utf-8", headers=fresh)

    async def view(request: Request) -> Response:
        return JSONResponse(await run_in_threadpool(desk.view), headers=fresh)

    async def frame(request: Request) -> Response:
        round, step = _integer(request, "round"), _integer(request, "step")
        image = await run_in_threadpool(desk.frame, round, step)
        return Response(await run_in_threadpool(png, image), media_type="image/png", headers=fresh)

    async def clip(request: Request) -> Response:
        frames = await run_in_threadpool(desk.clip)
        return Response(await run_in_threadpool(png, np.concatenate(frames, axis=1)), media_type="image/png")

    async def label(request: Request) -> Response:
        body = await _body(request, ("round", "step", "label"))
        if not all(isinstance(body[k], int) and not isinstance(body[k], bool) for k in ("round", "step")):
            raise Refused(f"round and step must be integers, got {body['round']!r} and {body['step']!r}")
        view = await run_in_threadpool(desk.answer, body["round"], body["step"], body["label"])
        return JSONResponse(view, headers=fresh)

    async def pause(request: Request) -> Response:
        body = await _body(request, ("paused",))
        if not isinstance(body["paused"], bool):
            raise Refused(f"paused must be true or false, got {body['paused']!r}")
        return JSONResponse(await run_in_threadpool(desk.pause, body["paused"]), headers=fresh)

    routes = [
        Route("/", index),
        Route("/page.js", js),
        Route("/api/view", guarded(view)),
        Route("/api/frame", guarded(frame)),
        Route("/api/clip", guarded(clip)),
        Route("/api/label", guarded(label), methods=["POST"]),
        Route("/api/pause", guarded(pause), methods=["POST"]),
    ]
    middleware = [
        Middleware(TrustedHostMiddleware, allowed_hosts=[LOOPBACK, "localhost"]),
        Middleware(TokenGate, token=token),
    ]
    return Starlette(routes=routes, middleware=middleware)


class TokenGate:
    """ASGI middleware: a request whose ``token`` query parameter is not the session's gets 403 and one line."""

    def __init__(self, app: Any, *, token: str) -> None:
        self.app, self._token = app, token.encode()

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] == "http":
            given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
            if not secrets.compare_digest(given.encode(), self._token):
                from starlette.responses import PlainTextResponse

                message = (
                    "refused: the request lacks this session's token; open the URL that `metadagger label` printed"
                )
                await PlainTextResponse(message, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _integer(request: Any, name: str) -> int:
    value = request.query_params.get(name, "")
    try:
        return int(value)
    except ValueError:
        raise Refused(f"{name} must be an integer, got {value!r}") from None


async def _body(request: Any, keys: tuple[str, ...]) -> dict[str, Any]:
    """The request's JSON object, holding ``keys``; anything else is :class:`Refused`."""
    try:
        body = json.loads(await request.body())
    except ValueError:
        body = None
    if not isinstance(body, dict) or set(body) != set(keys):
        raise Refused(f"expected a JSON object with {', '.join(keys)}")
    return body


class PageServer:
    """The page served on ``127.0.0.1:port`` (0: a free port) while the ``with`` block runs.

    Args:
        desk: what the page shows and answers.
        port: the port; a port that cannot be bound is a :class:`UserError`.
    """

    def __init__(self, desk: Desk, *, port: int = 0) -> None:
        _, uvicorn = require_server()
        self.token = secrets.token_urlsafe(24)
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._socket.bind((LOOPBACK, port))
        except OSError as exc:
            self._socket.close()
            raise UserError(
                f"--port {port} cannot be used on {LOOPBACK} ({exc.strerror}); choose another port, or 0 for a free one"
            ) from None
        self.port = int(self._socket.getsockname()[1])
        config = uvicorn.Config(
            make_app(desk, self.token),
            log_level="warning",
            access_log=False,
            lifespan="off",
            timeout_graceful_shutdown=1,
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(
            target=self._server.run, kwargs={"sockets": [self._socket]}, name="label-page", daemon=True
        )

    @property
    def url(self) -> str:
        """The page's address, with the token every request must carry."""
        return f"http://{LOOPBACK}:{self.port}/?token={self.token}"

    def __enter__(self) -> PageServer:
        self._thread.start()
        deadline = time.monotonic() + 30
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise UserError(f"the labelling page could not be served on {LOOPBACK}:{self.port}")
            time.sleep(0.02)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=5)
        self._socket.close()
