"""The labelling page in a real browser: headless Chromium as a scripted person.

The person answers each state the page shows with the task's scripted expert's label of it (read
from the scripted expert's session of the same gate), after a set delay, by the arrow keys and
Enter or by a click on the class. The command is stopped mid-round and run again on the same
port; the tab left open says its session ended, and the session finished at the new URL must make
the scripted session's heads and rows, byte for byte, with the delays as the ledger's seconds.
Needs Debian's chromium and chromium-driver and the browser extra (selenium); ``.ci/run``
installs them, and without them this test is skipped. With
``METADAGGER_DOCS_SCREENSHOT=docs/figures/label-page.png`` it also writes the screenshot docs/label.md shows.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import time
from pathlib import Path

import pytest
from corridor_session import SEED, command, session_args

from metadagger.evaluation.benchmark.ledger import PERSON, SCRIPTED, round_seconds
from metadagger.evaluation.report.label import label_section
from metadagger.label.session import plan_of_run, run_label
from metadagger.pipeline.run_config import load_run
from metadagger.utils.jsonl import read_lines

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
MISSING = [p for p in (CHROMIUM, CHROMEDRIVER) if not Path(p).is_file()]
webdriver = pytest.importorskip(
    "selenium.webdriver",
    reason="the browser test needs the browser extra (selenium) with Debian's chromium and chromium-driver; "
    ".ci/run installs them",
)
pytestmark = pytest.mark.skipif(
    bool(MISSING),
    reason=f"the browser test needs Debian's chromium and chromium-driver ({', '.join(MISSING)} missing); "
    ".ci/run installs them",
)
pytest.importorskip("starlette", reason="the label extra (starlette, uvicorn) is not installed")

#: The person's delay before each answer, in turn (seconds).
DELAYS = (0.2, 0.5, 0.3)
#: Before the answer of this label (0-based) the person opens the steps around the state, and the
#: screenshot is taken; its delay is longer.
SHOT, SHOT_DELAY = 6, 1.0
#: How much longer than its delay a label may be timed: the browser's round trips around the wait.
SLACK = 0.35
#: The script that waits for the page to show a state other than ``arguments[0]`` (its frame loaded);
#: returns "round/step", or null once the session is done.
NEXT_STATE = """
const [last, done] = [arguments[0], arguments[arguments.length - 1]];
const check = () => {
  const box = document.getElementById("state");
  const key = `${box.dataset.round}/${box.dataset.step}`;
  if (document.body.dataset.status === "done") return done(null);
  if (box.dataset.ready === "1" && key !== last) return done(key);
  setTimeout(check, 5);
};
check();
"""


@pytest.fixture
def browser(tmp_path, monkeypatch):
    """Headless Chromium through chromedriver, both Debian's (nothing is downloaded)."""
    from selenium.webdriver.chrome.service import Service

    monkeypatch.setenv("SE_OFFLINE", "true")  # Selenium Manager never fetches a browser or a driver
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--window-size=1100,860",
        f"--user-data-dir={tmp_path / 'chromium'}",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_script_timeout(120)
    yield driver
    driver.quit()


def _url(process) -> str:
    for line in process.stdout:
        if line.startswith("label the states at "):
            return line.split()[-1]
    raise AssertionError(f"the command printed no URL: {process.stderr.read()}")


class Person:
    """A scripted person at the page: the scripted expert's labels, given after :data:`DELAYS`."""

    def __init__(self, driver, answers: dict[tuple[int, int], int], screenshot: Path) -> None:
        self.driver, self.answers, self.screenshot = driver, answers, screenshot
        self.given: list[tuple[tuple[int, int], float]] = []
        self.last = ""

    def label(self, count: int) -> None:
        """Give ``count`` labels (or, with -1, every one until the session is done)."""
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        while count:
            shown = self.driver.execute_async_script(NEXT_STATE, self.last)
            if shown is None:
                return
            delay = DELAYS[len(self.given) % len(DELAYS)] if len(self.given) != SHOT else SHOT_DELAY
            answer_at = time.monotonic() + delay
            self.last = shown
            state = tuple(int(x) for x in shown.split("/"))
            if len(self.given) == SHOT:  # a look at the steps around the state, and the screenshot
                classes = self.driver.find_element(By.ID, "classes").rect
                ActionChains(self.driver).send_keys("a").perform()
                time.sleep(0.3)
                self.driver.save_screenshot(str(self.screenshot))
                assert self.driver.find_element(By.ID, "classes").rect == classes  # the buttons stay put
            time.sleep(answer_at - time.monotonic())
            target = self.answers[state]
            if len(self.given) % 2 == 0:  # the keys: move the choice to the class, then Enter
                choice = int(
                    self.driver.find_element(By.CSS_SELECTOR, "#classes button.selected").get_attribute("data-label")
                )
                arrow = Keys.ARROW_RIGHT if target > choice else Keys.ARROW_LEFT
                ActionChains(self.driver).send_keys(arrow * abs(target - choice) + Keys.ENTER).perform()
            else:  # the mouse: a click on the class
                self.driver.find_element(By.CSS_SELECTOR, f'#classes button[data-label="{target}"]').click()
            self.given.append((state, delay))
            count -= 1


def test_a_person_in_chromium_makes_the_scripted_experts_heads_and_rows(run, corridor_site, browser, tmp_path):
    plan = plan_of_run(run, load_run(run.root), seed=SEED, gate="safe", setting=0.5)
    run_label(run, plan, expert=SCRIPTED)
    scripted = run.label_session(SCRIPTED, "dagger-safe", "0.5", SEED)
    answers = {(r["round"], r["step"]): r["label"] for r in read_lines(scripted.labels, called="label")}
    person = Person(browser, answers, tmp_path / "label-page.png")
    with socket.socket() as probe:  # a fixed port, as one forwarded over ssh
        probe.bind(("127.0.0.1", 0))
        port = str(probe.getsockname()[1])

    first = command(corridor_site, *session_args(run.root, "--port", port))
    browser.get(_url(first))
    person.label(4)
    first.send_signal(signal.SIGTERM)  # the command stopped mid-session, the page left open
    _, err = first.communicate(timeout=60)
    assert first.returncode == 143 and "stopped by SIGTERM: finished work is kept" in err, err
    session = run.label_session(PERSON, "dagger-safe", "0.5", SEED)
    assert len(read_lines(session.labels, called="label")) == 4

    second = command(corridor_site, *session_args(run.root, "--port", port))  # the same port, at once
    url = _url(second)
    deadline = time.monotonic() + 10
    while "session has ended" not in browser.find_element("id", "message").text:  # the tab left open
        assert time.monotonic() < deadline, browser.find_element("id", "message").text
        time.sleep(0.1)
    assert "Open the URL it printed last" in browser.find_element("id", "message").text
    browser.get(url)  # the new URL: a new token
    person.label(-1)
    _, err = second.communicate(timeout=60)
    assert second.returncode == 0, err
    assert "done: 3 rounds" in browser.find_element("id", "message").text
    assert not browser.find_element("id", "frame").is_displayed()  # nothing left to show, no broken image

    assert session.rows.read_bytes() == scripted.rows.read_bytes()
    for index in (1, 2, 3):
        assert session.head(index).read_bytes() == scripted.head(index).read_bytes()
    records = read_lines(session.labels, called="label")
    assert [((r["round"], r["step"]), r["label"]) for r in records] == sorted(answers.items())
    assert [(r["round"], r["step"]) for r in records] == [state for state, _ in person.given]
    late = [round(r["seconds"] - delay, 3) for r, (_, delay) in zip(records, person.given)]
    assert all(r["who"] == PERSON for r in records) and all(0 <= x <= SLACK for x in late), late
    section = "\n".join(label_section(run))
    assert "DAgger, SafeDAgger gate 0.5, seed 300, labelled by person" in section
    assert "labelled by scripted" in section
    last = read_lines(session.rows, called="row")[-1]
    # the ledger keeps the seconds' sum to the millisecond; the table shows that sum to a tenth
    seconds = round_seconds(sum(r["seconds"] for r in records))
    switches = sum(r["switch"] for r in records)
    outcome = f"{'success' if last['success'] else 'failure'} ({last['steps']} steps)"
    line = f"| 3 | {outcome} | {last['expert_queries']} | {last['takeovers']} | {len(records)} | {seconds:.1f} |"
    assert f"{line} {switches} | person |" in section

    assert person.screenshot.stat().st_size > 10_000
    target = os.environ.get("METADAGGER_DOCS_SCREENSHOT")
    if target:
        shutil.copyfile(person.screenshot, target)
