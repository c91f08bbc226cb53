"""The labelling page's web server: on the loopback address only, every request carrying the session's token.

A small Starlette app served by uvicorn in a thread of the command. It serves the package's page
(``page.html``, ``page.js``) and, from memory, the frames of the state asked now and its
neighbours, the state's overview where the task has one, and a clip of the learner's last rollout
(:class:`~metadagger.label.desk.Desk`); it reads no file of the run folder or anywhere else. A
request without the random token of the printed URL, or naming another host than the loopback
one, is refused, and so is a body longer than :data:`MAX_BODY` before any of it is read.
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
from metadagger.label.forms import Refused, clipped, shown

#: The address the page is served on: this machine alone.
LOOPBACK = "127.0.0.1"
#: Where the token stands in the page's HTML.
TOKEN_MARK = "__TOKEN__"
#: The longest request body taken, in bytes: a label is a few bytes, an action vector of a hundred numbers 2 KB.
MAX_BODY = 4096
#: The largest round or step a request may name (a rollout's steps are far fewer).
MAX_INDEX = 10**9
#: What a request with another token is told: the page of an earlier run of the command, or a URL without it.
WRONG_TOKEN = (
    "refused: the request lacks the token of the session served here (a page left open from an earlier run of "
    "the command holds that run's); open the URL that `metadagger label` printed last"
)


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
        if "shows" in request.query_params:  # the page's word on the state it shows (desk.Desk.showing)
            await run_in_threadpool(desk.showing, _shows(request.query_params["shows"]))
        return JSONResponse(await run_in_threadpool(desk.view), headers=fresh)

    async def frame(request: Request) -> Response:
        round, step = _integer(request, "round"), _integer(request, "step")
        image = await run_in_threadpool(desk.frame, round, step)
        return Response(await run_in_threadpool(png, image), media_type="image/png", headers=fresh)

    async def overview(request: Request) -> Response:
        round, step = _integer(request, "round"), _integer(request, "step")
        image = await run_in_threadpool(desk.overview, round, step)
        return Response(await run_in_threadpool(png, image), media_type="image/png", headers=fresh)

    async def clip(request: Request) -> Response:
        frames = await run_in_threadpool(desk.clip)
        return Response(await run_in_threadpool(png, np.concatenate(frames, axis=1)), media_type="image/png")

    async def label(request: Request) -> Response:
        body = await _body(request, ("round", "step", "label"))
        round, step = _index("round", body["round"]), _index("step", body["step"])
        view = await run_in_threadpool(desk.answer, round, step, body["label"])
        return JSONResponse(view, headers=fresh)

    async def pause(request: Request) -> Response:
        body = await _body(request, ("paused",))
        if not isinstance(body["paused"], bool):
            raise Refused(f"paused must be true or false, got {shown(body['paused'])}")
        return JSONResponse(await run_in_threadpool(desk.pause, body["paused"]), headers=fresh)

    routes = [
        Route("/", index),
        Route("/page.js", js),
        Route("/api/view", guarded(view)),
        Route("/api/frame", guarded(frame)),
        Route("/api/clip", guarded(clip)),
        Route("/api/overview", guarded(overview)),
        Route("/api/label", guarded(label), methods=["POST"]),
        Route("/api/pause", guarded(pause), methods=["POST"]),
    ]
    middleware = [
        Middleware(TrustedHostMiddleware, allowed_hosts=[LOOPBACK, "localhost"]),
        Middleware(BodyLimit),
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

                await PlainTextResponse(WRONG_TOKEN, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)


class BodyLimit:
    """ASGI middleware: a request whose body is longer than :data:`MAX_BODY`, or of a length it does not
    declare, gets 413 and one line before any of it is read, and its connection is closed."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] == "http":
            headers = dict(scope.get("headers", []))
            declared = headers.get(b"content-length", b"0").decode("latin-1")
            chunked = b"transfer-encoding" in headers
            if chunked or not _decimal(declared) or int(declared) > MAX_BODY:
                from starlette.responses import JSONResponse

                said = "a length it does not declare" if chunked else f"{clipped(declared)} bytes"
                message = (
                    f"refused: a request body of {said}; the page takes at most {MAX_BODY} bytes, its length "
                    "declared (a label is a few bytes)"
                )
                response = JSONResponse({"error": message}, status_code=413, headers={"Connection": "close"})
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _decimal(text: str) -> bool:
    """Whether ``text`` is a non-negative integer of at most :data:`MAX_INDEX`'s digits."""
    return text.isascii() and text.isdigit() and len(text) <= len(str(MAX_INDEX))


def _integer(request: Any, name: str) -> int:
    """Query parameter ``name`` as a round or step; anything else is :class:`Refused`."""
    return _parsed(name, request.query_params.get(name, ""))


def _parsed(name: str, text: str) -> int:
    """``text`` as a round or step; anything else is :class:`Refused`."""
    if not _decimal(text):
        raise Refused(f"{name} must be an integer from 0 to {MAX_INDEX}, got {shown(text)}")
    return _index(name, int(text))


def _index(name: str, value: Any) -> int:
    """``value`` as a round or step: an integer in [0, :data:`MAX_INDEX`]; anything else is :class:`Refused`."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_INDEX:
        raise Refused(f"{name} must be an integer from 0 to {MAX_INDEX}, got {shown(value)}")
    return value


def _shows(text: str) -> tuple[int, int] | None:
    """The state a page says it shows, ``round/step``; empty: none."""
    if not text:
        return None
    round, _, step = text.partition("/")
    return _parsed("round", round), _parsed("step", step)


async def _body(request: Any, keys: tuple[str, ...]) -> dict[str, Any]:
    """The request's JSON object, holding ``keys``; anything else is :class:`Refused`."""
    try:
        body = json.loads(await request.body())
    except ValueError as exc:  # the message names a place in a body of at most MAX_BODY bytes
        raise Refused(f"the body is not JSON ({exc}); expected an object with {', '.join(keys)}") from None
    if not isinstance(body, dict) or set(body) != set(keys):
        got = f"keys {shown(sorted(body))}" if isinstance(body, dict) else f"a {type(body).__name__}"
        raise Refused(f"expected a JSON object with {', '.join(keys)}, got {got}")
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
        # a restart on the same --port binds at once, while the last run's connections linger in TIME_WAIT
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
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
