"""The labelling page's server over plain HTTP: the token, what it serves, the refusals, the clock; and a
person's session answered over HTTP, killed mid-round and resumed, against the scripted expert's."""

from __future__ import annotations

import json
import signal
import threading
import time
import urllib.error
import urllib.request
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from corridor_session import SEED, command, session_args

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.ledger import PERSON, SCRIPTED
from metadagger.label.desk import Desk
from metadagger.label.forms import LabelForm
from metadagger.label.session import plan_of_run, run_label
from metadagger.label.store import LabelStore
from metadagger.pipeline.run_config import load_run
from metadagger.utils.jsonl import read_lines

pytest.importorskip("starlette", reason="the label extra (starlette, uvicorn) is not installed")
from metadagger.label.server import PageServer  # noqa: E402


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _request(url: str, body: dict | None = None, host: str | None = None) -> tuple[int, bytes]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    if host is not None:
        request.add_unredirected_header("Host", host)
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


@pytest.fixture
def page(tmp_path):
    """A page asking round 1 steps 2, 3 and 7 of a ten-step rollout of 4x4 frames (frame i all i),
    while a loop thread waits for the labels; yields (server, store, clock, loop thread)."""
    frames = np.stack([np.full((4, 4, 3), i, np.uint8) for i in range(10)])
    rollout = SimpleNamespace(obs=frames, steps=10, success=False, reward=3.0)
    store = LabelStore(tmp_path / "labels.jsonl", seed=SEED)
    clock = Clock()
    desk = Desk(store, LabelForm(classes=("left", "straight", "right")), seed=SEED, rounds=2, title="t", clock=clock)
    desk.working("starting", round=0, queries=30)
    with PageServer(desk) as server:
        loop = threading.Thread(target=desk.ask, args=(1, rollout, np.array([2, 3, 7]), [2, 3, 7]), daemon=True)
        loop.start()
        yield server, store, clock, loop


def _api(server: PageServer, path: str, **params: Any) -> str:
    query = "&".join(f"{k}={v}" for k, v in {**params, "token": server.token}.items())
    return f"http://127.0.0.1:{server.port}/api/{path}?{query}"


def test_every_request_needs_the_token_and_the_loopback_host(page):
    server, store, *_ = page
    assert server.url == f"http://127.0.0.1:{server.port}/?token={server.token}" and len(server.token) >= 32
    status, html = _request(server.url)
    assert status == 200 and f"page.js?token={server.token}" in html.decode()
    bare = f"http://127.0.0.1:{server.port}"
    for url in (f"{bare}/", f"{bare}/page.js", f"{bare}/api/view", f"{bare}/?token=guess", f"{bare}/api/view?token="):
        status, body = _request(url)
        assert status == 403 and body.decode().startswith("refused: the request lacks this session's token")
    status, _ = _request(server.url, host="attacker.example")  # a page of another site, rebinding its name
    assert status == 400
    status, _ = _request(f"{bare}/../config.yaml?token={server.token}")
    assert status == 404  # nothing but the page and the asked frames is served
    status, _ = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1}, host="attacker.example")
    assert status == 400 and not store.path.exists()


def test_the_page_shows_the_asked_states_in_step_order_and_times_each_label(page):
    server, store, clock, loop = page
    view = json.loads(_request(_api(server, "view"))[1])
    assert view["status"] == "asking" and view["state"] == {"round": 1, "step": 2, "steps": 10, "neighbours": 8}
    assert (view["queries"], view["asked"], view["answered"]) == (30, 3, 0)
    assert view["form"] == {"classes": ["left", "straight", "right"]} and view["clip"]["frames"] == 10

    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1})
    assert status == 409 and "is not the state shown now" in json.loads(body)["error"]  # its frame not served yet
    status, png = _request(_api(server, "frame", round=1, step=2))
    assert status == 200 and png.startswith(b"\x89PNG")  # shown: its clock starts at 100
    clock.now = 102.5
    assert _request(_api(server, "frame", round=1, step=9))[0] == 200  # a neighbour, on demand
    for params, says in (
        ({"round": 1, "step": 2, "label": 3}, "label 3 refused: expected a class index in [0, 2]"),
        ({"round": 1, "step": 4, "label": 1}, "round 1 step 4 was not asked: the gate chose other states"),
        ({"round": 1, "step": 3, "label": 1}, "round 1 step 3 is not the state shown now"),
        ({"round": 2, "step": 2, "label": 1}, "round 2 step 2 is not asked now"),
        ({"round": 1, "step": 2}, "expected a JSON object with round, step, label"),
    ):
        status, body = _request(_api(server, "label"), params)
        assert status in (400, 409) and json.loads(body)["error"].startswith(says)
    assert not store.path.exists()  # nothing written

    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 0})
    view = json.loads(body)
    assert status == 200 and view["state"]["step"] == 3 and (view["queries"], view["answered"]) == (31, 1)
    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 2})
    assert status == 409 and "labelled already: a label is given once" in json.loads(body)["error"]
    assert len(store.path.read_text().splitlines()) == 1

    _request(_api(server, "frame", round=1, step=3))
    _request(_api(server, "pause"), {"paused": True})
    assert _request(_api(server, "label"), {"round": 1, "step": 3, "label": 1})[0] == 409  # paused
    clock.now = 160.0  # a break: no labelling time
    assert json.loads(_request(_api(server, "pause"), {"paused": False})[1])["status"] == "asking"
    clock.now = 161.25
    assert _request(_api(server, "label"), {"round": 1, "step": 3, "label": 1})[0] == 200
    _request(_api(server, "frame", round=1, step=7))
    clock.now = 165.0
    assert _request(_api(server, "label"), {"round": 1, "step": 7, "label": 2})[0] == 200
    loop.join(timeout=10)
    assert not loop.is_alive()  # the round's last label ends the loop's wait
    records = read_lines(store.path, called="label")
    assert [(r["step"], r["label"], r["seconds"], r["switch"], r["who"]) for r in records] == [
        (2, 0, 2.5, True, PERSON),
        (3, 1, 1.25, False, PERSON),  # shown at 102.5, paused from 102.5 to 160
        (7, 2, 3.75, True, PERSON),
    ]
    view = json.loads(_request(_api(server, "view"))[1])
    assert view["state"] is None and view["queries"] == 33
    assert _request(_api(server, "frame", round=1, step=7))[0] == 404  # no state asked: no frame served


def _answer_over_http(url: str, answers: dict[tuple[int, int], int], count: int) -> int:
    """A scripted person at ``url``: ``count`` labels (-1: until the session is done), each the scripted expert's
    label of the state shown; how many it gave."""
    base, token = url.split("/?token=")
    given = 0
    while given != count:
        try:
            view = json.loads(_request(f"{base}/api/view?token={token}")[1])
        except urllib.error.URLError:  # the command has ended
            break
        if view["status"] == "done":
            break
        state = view["state"]
        if state is None:
            time.sleep(0.05)  # the loop refits and rolls out
            continue
        _request(f"{base}/api/frame?round={state['round']}&step={state['step']}&token={token}")
        label = answers[(state["round"], state["step"])]
        body = {"round": state["round"], "step": state["step"], "label": label}
        status, body = _request(f"{base}/api/label?token={token}", body)
        assert status == 200, body
        given += 1
    return given


def _url(process) -> str:
    for line in process.stdout:
        if line.startswith("label the states at "):
            return line.split()[-1]
    raise AssertionError(f"the command printed no URL: {process.stderr.read()}")


def test_a_killed_session_loses_no_label_and_resumes_to_the_scripted_experts_heads_and_rows(run, corridor_site):
    scripted = run_label(
        run, plan_of_run(run, load_run(run.root), seed=SEED, gate="safe", setting=0.5), expert=SCRIPTED
    )
    mine = run.label_session(SCRIPTED, "dagger-safe", "0.5", SEED)
    answers = {(r["round"], r["step"]): r["label"] for r in read_lines(mine.labels, called="label")}
    person = run.label_session(PERSON, "dagger-safe", "0.5", SEED)

    first = command(corridor_site, *session_args(run.root))
    try:
        assert _answer_over_http(_url(first), answers, 5) == 5
    finally:
        first.send_signal(signal.SIGKILL)  # no chance to clean up
        first.wait(timeout=30)
    assert len(read_lines(person.labels, called="label")) == 5  # every label given is on disk

    second = command(corridor_site, *session_args(run.root))
    url = _url(second)
    assert _answer_over_http(url, answers, -1) == len(answers) - 5  # asked only what was missing
    out, err = second.communicate(timeout=60)
    assert second.returncode == 0, err
    assert f"round 3: success at {scripted[-1]['expert_queries']} queries, {len(answers)} labelled by person" in out

    assert person.rows.read_bytes() == mine.rows.read_bytes()
    for index in (1, 2, 3):
        assert person.head(index).read_bytes() == mine.head(index).read_bytes()
    records = read_lines(person.labels, called="label")
    assert {(r["round"], r["step"]): r["label"] for r in records} == answers
    assert all(r["who"] == PERSON and r["seconds"] >= 0 for r in records)


def test_a_port_in_use_is_one_line(tmp_path, closed_port):
    desk = Desk(LabelStore(tmp_path / "l.jsonl", 1), LabelForm(classes=("a", "b")), seed=1, rounds=1, title="t")
    with pytest.raises(UserError, match=f"--port {closed_port} cannot be used on 127.0.0.1 .*choose another port"):
        PageServer(desk, port=closed_port)
