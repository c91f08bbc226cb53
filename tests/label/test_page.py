"""The labelling page's server over plain HTTP: the token, what it serves, the refusals, the bounded
requests, the clock, a restart on a fixed port; and a person's session answered over HTTP, killed
mid-round and resumed, against the scripted expert's, then run again once finished."""

from __future__ import annotations

import dataclasses
import http.client
import json
import signal
import socket
import threading
import time
import urllib.error
import urllib.request
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from corridor_session import SEED, command, session_args
from toy_task import RunCorridorTask
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.evaluation.benchmark.ledger import PERSON, SCRIPTED
from metadagger.label.desk import SILENCE, Desk
from metadagger.label.forms import LabelForm
from metadagger.label.overview import Overview
from metadagger.label.session import plan_of_run, run_label
from metadagger.label.store import LabelStore
from metadagger.pipeline.run_config import load_run
from metadagger.utils.jsonl import read_lines

pytest.importorskip("starlette", reason="the label extra (starlette, uvicorn) is not installed")
from metadagger.label.server import MAX_BODY, WRONG_TOKEN, PageServer  # noqa: E402


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


def _overview(step: int) -> np.ndarray:
    """A stand-in for a task's overview of step ``step``: a 6x6 picture, all ``100 + step``."""
    return np.full((6, 6, 3), 100 + step, np.uint8)


@pytest.fixture
def page(tmp_path):
    """A page asking round 1 steps 2, 3 and 7 of a ten-step rollout of 4x4 frames (frame i all i), with
    an overview of each step, while a loop thread waits for the labels; yields (server, store, clock,
    loop thread)."""
    frames = np.stack([np.full((4, 4, 3), i, np.uint8) for i in range(10)])
    rollout = SimpleNamespace(obs=frames, steps=10, success=False, reward=3.0)
    store = LabelStore(tmp_path / "labels.jsonl", seed=SEED)
    clock = Clock()
    form = LabelForm(classes=("left", "straight", "right"), marks=((1, "straight"),))
    desk = Desk(store, form, seed=SEED, rounds=2, title="t", overview="the map", clock=clock)
    desk.working("starting", round=0, queries=30)
    with PageServer(desk) as server:
        asked = (1, rollout, np.array([2, 3, 7]), [2, 3, 7], _overview)
        loop = threading.Thread(target=desk.ask, args=asked, daemon=True)
        loop.start()
        while json.loads(_request(_api(server, "view"))[1])["state"] is None:
            time.sleep(0.01)  # the loop thread has not asked yet
        yield server, store, clock, loop


def _post(url: str, data: bytes) -> tuple[int, bytes]:
    """POST ``data`` as it is (a body ``json.dumps`` could not write, or would not) to ``url``."""
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def _api(server: PageServer, path: str, **params: Any) -> str:
    query = "&".join(f"{k}={v}" for k, v in {**params, "token": server.token}.items())
    return f"http://127.0.0.1:{server.port}/api/{path}?{query}"


def _shows(server: PageServer, state: str) -> dict:
    """The page's word that it shows ``state`` ("round/step"; "": none), and the view it gets back."""
    status, body = _request(_api(server, "view", shows=state))
    assert status == 200, body
    return json.loads(body)


def test_every_request_needs_the_token_and_the_loopback_host(page):
    server, store, *_ = page
    assert server.url == f"http://127.0.0.1:{server.port}/?token={server.token}" and len(server.token) >= 32
    status, html = _request(server.url)
    assert status == 200 and f"page.js?token={server.token}" in html.decode()
    bare = f"http://127.0.0.1:{server.port}"
    for url in (f"{bare}/", f"{bare}/page.js", f"{bare}/api/view", f"{bare}/?token=guess", f"{bare}/api/view?token="):
        status, body = _request(url)
        assert status == 403 and body.decode() == WRONG_TOKEN
    status, _ = _request(server.url, host="attacker.example")  # a page of another site, rebinding its name
    assert status == 400
    status, _ = _request(f"{bare}/../config.yaml?token={server.token}")
    assert status == 404  # nothing but the page and the asked frames is served
    status, _ = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1}, host="attacker.example")
    assert status == 400 and not store.path.exists()


def test_the_page_shows_the_asked_states_in_step_order_and_times_each_label(page):
    server, store, clock, loop = page
    view = json.loads(_request(_api(server, "view"))[1])
    assert view["status"] == "asking"
    assert view["state"] == {"round": 1, "step": 2, "steps": 10, "neighbours": 8, "overview": True}
    assert (view["queries"], view["asked"], view["answered"]) == (30, 3, 0)
    assert view["form"]["classes"] == ["left", "straight", "right"] and view["form"]["marks"] == {"1": "straight"}
    assert view["form"]["asks"] and view["overview"] == "the map" and view["clip"]["frames"] == 10

    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1})
    assert status == 409 and "is not the state shown now" in json.loads(body)["error"]  # its frame not served yet
    status, png = _request(_api(server, "frame", round=1, step=2))
    assert status == 200 and png.startswith(b"\x89PNG")
    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1})
    assert status == 409 and "is not the state shown now" in json.loads(body)["error"]  # no page said it shows it
    _shows(server, "1/2")  # the page shows it: its clock starts at 100
    clock.now = 102.0
    _shows(server, "1/2")
    clock.now = 102.5
    assert _request(_api(server, "frame", round=1, step=10))[0] == 404  # a neighbour beyond the episode
    assert _request(_api(server, "frame", round=1, step=9))[0] == 200  # a neighbour, on demand
    status, picture = _request(_api(server, "overview", round=1, step=2))
    assert status == 200 and picture.startswith(b"\x89PNG")
    assert _request(_api(server, "overview", round=1, step=3))[0] == 404  # the state shown now alone
    for params, says in (
        ({"round": 1, "step": 2, "label": 3}, "label 3 refused: expected a class index in [0, 2]"),
        ({"round": 1, "step": 4, "label": 1}, "round 1 step 4 was not asked: the gate chose other states"),
        ({"round": 1, "step": 12, "label": 1}, "round 1 has steps 0 to 9, not 12"),
        ({"round": 1, "step": 3, "label": 1}, "round 1 step 3 is not the state shown now"),
        ({"round": 2, "step": 2, "label": 1}, "round 2 step 2 is not asked now"),
        ({"round": 1, "step": -1, "label": 1}, "step must be an integer from 0 to 1000000000, got -1"),
        ({"round": 1, "step": 2}, "expected a JSON object with round, step, label, got keys ['round', 'step']"),
    ):
        status, body = _request(_api(server, "label"), params)
        assert status in (400, 409) and json.loads(body)["error"].startswith(says), body
    assert not store.path.exists()  # nothing written

    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 0})
    view = json.loads(body)
    assert status == 200 and view["state"]["step"] == 3 and (view["queries"], view["answered"]) == (31, 1)
    status, body = _request(_api(server, "label"), {"round": 1, "step": 2, "label": 2})
    assert status == 409 and "labelled already: a label is given once" in json.loads(body)["error"]
    assert len(store.path.read_text().splitlines()) == 1

    _request(_api(server, "frame", round=1, step=3))
    _shows(server, "1/3")
    _request(_api(server, "pause"), {"paused": True})
    assert _request(_api(server, "label"), {"round": 1, "step": 3, "label": 1})[0] == 409  # paused
    clock.now = 160.0  # a break: no labelling time, whatever the page says meanwhile
    _shows(server, "1/3")
    assert json.loads(_request(_api(server, "pause"), {"paused": False})[1])["status"] == "asking"
    clock.now = 161.25
    assert _request(_api(server, "label"), {"round": 1, "step": 3, "label": 1})[0] == 200
    _request(_api(server, "frame", round=1, step=7))
    _shows(server, "1/7")
    clock.now = 163.0
    _shows(server, "1/7")
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


def test_a_states_clock_runs_only_while_a_page_shows_it(page):
    server, store, clock, loop = page
    _request(_api(server, "frame", round=1, step=2))
    clock.now = 190.0  # an idle served frame: no page says it shows it
    _shows(server, "1/2")
    clock.now = 191.0
    _shows(server, "1/2")  # 1 s
    clock.now = 191.5
    _shows(server, "")  # the tab hidden: 0.5 s, then nothing
    clock.now = 230.0
    _shows(server, "1/2")  # visible again
    clock.now = 231.0
    _shows(server, "1/2")  # 1 s
    clock.now = 231.0 + SILENCE + 15  # the page closed without a word, then opened again
    _shows(server, "1/2")
    clock.now += 0.25
    _shows(server, "1/3")  # a word on another state counts nothing
    clock.now += 0.25
    assert _request(_api(server, "label"), {"round": 1, "step": 2, "label": 1})[0] == 200  # 0.5 s
    _request(_api(server, "frame", round=1, step=3))
    _shows(server, "1/3")
    clock.now += SILENCE + 30  # a page fell silent, then its label arrives: nothing since its last word
    assert _request(_api(server, "label"), {"round": 1, "step": 3, "label": 1})[0] == 200
    assert [r["seconds"] for r in read_lines(store.path, called="label")] == [3.0, 0.0]


def test_a_request_body_is_bounded_and_a_refusal_never_echoes_it_whole(page):
    server, store, *_ = page
    _request(_api(server, "frame", round=1, step=2))
    _shows(server, "1/2")
    path = _api(server, "label").split(f":{server.port}", 1)[1]
    # 400 MB announced and not sent: refused at once, before any of it is read
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as raw:
        head = f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 400000000\r\n\r\n"
        raw.sendall(head.encode())
        started = time.monotonic()
        answer = b"".join(iter(lambda: raw.recv(65536), b"")).decode()  # to the end: the server closes
    assert answer.startswith("HTTP/1.1 413") and time.monotonic() - started < 5
    assert f"refused: a request body of 400000000 bytes; the page takes at most {MAX_BODY} bytes" in answer
    connection = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    connection.putrequest("POST", path)
    connection.putheader("Transfer-Encoding", "chunked")
    connection.endheaders()
    connection.send(b"2\r\n{}\r\n0\r\n\r\n")
    response = connection.getresponse()
    assert response.status == 413 and "a length it does not declare" in json.loads(response.read())["error"]
    connection.close()

    label = b'{"round": 1, "step": 2, "label": %s}'
    for data, code, says in (
        (label % json.dumps([0.5] * 2000).encode(), 413, "refused: a request body of 10034 bytes"),
        (label % (b"9" * 100_000), 413, "refused: a request body of 100034 bytes"),
        (label % json.dumps([0.5] * 500).encode(), 400, "label [0.5, 0.5, "),
        (label % (b"9" * 4000), 400, "label 99999"),
        (b'{"round": %s, "step": 2, "label": 1}' % (b"9" * 4000), 400, "round must be an integer from 0 to 10"),
        (label % json.dumps("x" * 3000).encode(), 400, "label 'xxxx"),
    ):
        status, answer = _post(_api(server, "label"), data)
        error = json.loads(answer)["error"]
        assert status == code and error.startswith(says), error[:200]
        assert len(error) < 240, error  # one short line, whatever the value
    status, answer = _request(_api(server, "frame", round="9" * 5000, step=2))
    assert status == 400 and len(json.loads(answer)["error"]) < 240
    status, answer = _request(_api(server, "view", shows="1/" + "9" * 5000))
    assert status == 400 and len(json.loads(answer)["error"]) < 240
    status, answer = _request(_api(server, "pause"), {"paused": "y" * 3000})
    assert status == 400 and len(json.loads(answer)["error"]) < 240
    status, answer = _post(_api(server, "label"), b"{not json")
    assert status == 400 and json.loads(answer)["error"].startswith("the body is not JSON (Expecting property name")
    assert not store.path.exists()
    assert json.loads(_request(_api(server, "view"))[1])["state"]["step"] == 2  # the page serves on


def test_a_restart_on_a_fixed_port_binds_at_once_and_the_old_page_is_told_its_session_ended(tmp_path):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    desk = Desk(LabelStore(tmp_path / "l.jsonl", 1), LabelForm(classes=("a", "b")), seed=1, rounds=1, title="t")
    with PageServer(desk, port=port) as first:
        tab = http.client.HTTPConnection("127.0.0.1", port, timeout=10)  # an open tab's kept-alive connection
        tab.request("GET", f"/api/view?token={first.token}")
        assert tab.getresponse().read() and first.port == port
    # the old run closed the tab's connection: the port's side of it lingers in TIME_WAIT for a minute
    with PageServer(desk, port=port) as second:
        assert second.token != first.token
        status, body = _request(f"http://127.0.0.1:{port}/api/view?token={first.token}")
        assert status == 403 and body.decode() == WRONG_TOKEN
    tab.close()


def _answer_over_http(url: str, answers: dict[tuple[int, int], int], count: int, overview: bool = False) -> int:
    """A scripted person at ``url``: ``count`` labels (-1: until the session is done), each the scripted expert's
    label of the state shown, looking at its overview first where ``overview`` (:class:`Steps`'s picture of the
    step); how many it gave."""
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
        _request(f"{base}/api/view?shows={state['round']}/{state['step']}&token={token}")  # the page shows it
        if overview:
            status, png = _request(f"{base}/api/overview?round={state['round']}&step={state['step']}&token={token}")
            picture = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
            assert status == 200 and state["overview"] and (picture == state["step"]).all()
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

    again = CliRunner().invoke(app, session_args(run.root))  # finished: nothing replayed, no page served
    assert again.exit_code == 0, again.output
    assert f"session {person.root} is finished: nothing is left to label" in again.output
    assert "label the states at" not in again.output and f"`metadagger report --out {run.root}`" in again.output
    assert read_lines(person.labels, called="label") == records


class Steps(Overview):
    """An overview of the corridor's states: the env's own step count, as a grey level."""

    caption = "the step"

    def snapshot(self, env) -> int:
        return env.unwrapped._t

    def draw(self, snapshots, step: int) -> np.ndarray:
        return np.full((4, 4), snapshots[step], np.uint8)


class MappedCorridor(RunCorridorTask):
    """The run's corridor with an overview of its states."""

    def person_overview(self) -> Overview:
        return Steps()


def test_a_persons_session_shows_each_states_overview_and_its_episodes_are_the_scripted_ones(run):
    plan = plan_of_run(run, load_run(run.root), seed=SEED, gate="safe", setting=0.5)
    run_label(run, plan, expert=SCRIPTED)
    scripted = run.label_session(SCRIPTED, "dagger-safe", "0.5", SEED)
    answers = {(r["round"], r["step"]): r["label"] for r in read_lines(scripted.labels, called="label")}
    given: list[int] = []

    def person(url: str) -> None:
        def answer() -> None:
            given.append(_answer_over_http(url, answers, -1, overview=True))

        threading.Thread(target=answer, daemon=True).start()

    mapped = dataclasses.replace(plan, task=MappedCorridor(max_episode_steps=plan.task.max_episode_steps))
    rows = run_label(run, mapped, expert=PERSON, announce=person)
    assert given == [len(answers)]  # each state's overview was the step's own: the snapshots and the states agree
    person_session = run.label_session(PERSON, "dagger-safe", "0.5", SEED)
    assert rows == read_lines(scripted.rows, called="row")  # the recording env drives the same episodes
    assert person_session.rows.read_bytes() == scripted.rows.read_bytes()


def test_a_port_in_use_is_one_line(tmp_path, closed_port):
    desk = Desk(LabelStore(tmp_path / "l.jsonl", 1), LabelForm(classes=("a", "b")), seed=1, rounds=1, title="t")
    with pytest.raises(UserError, match=f"--port {closed_port} cannot be used on 127.0.0.1 .*choose another port"):
        PageServer(desk, port=closed_port)
