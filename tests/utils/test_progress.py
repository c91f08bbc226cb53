"""Progress: milestone lines where the output is not a terminal, tqdm bars where it is."""

from __future__ import annotations

import io
import subprocess
import sys

from metadagger.utils.progress import note, progress_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_one_line_per_quarter_with_the_last_postfix() -> None:
    log = io.StringIO()
    bar = progress_bar(range(100), desc="pairs", stream=log)
    for i in bar:
        bar.set_postfix(loss=f"{i:.1f}")
    lines = log.getvalue().splitlines()
    assert [line.split(" in ")[0] for line in lines] == [
        "pairs: 25/100",
        "pairs: 50/100",
        "pairs: 75/100",
        "pairs: 100/100",
    ]
    assert "left" in lines[0] and "left" not in lines[-1]
    assert lines[-1].endswith("(loss=99.0)")


def test_short_loops_report_every_item_and_nested_loops_stay_silent() -> None:
    log = io.StringIO()
    for _ in progress_bar(range(3), desc="rounds", stream=log):
        for _ in progress_bar(range(50), desc="epochs", stream=log, leave=False):
            pass
    assert [line.split(" in ")[0] for line in log.getvalue().splitlines()] == [
        "rounds: 1/3",
        "rounds: 2/3",
        "rounds: 3/3",
    ]


def test_unknown_length_and_disabled_loops_print_nothing_but_yield_everything() -> None:
    log = io.StringIO()
    assert list(progress_bar(iter(range(5)), desc="x", stream=log)) == list(range(5))
    assert list(progress_bar(range(5), desc="x", stream=log, enabled=False)) == list(range(5))
    assert log.getvalue() == ""


def test_a_note_is_one_line_inside_a_loop_and_nothing_when_disabled() -> None:
    log = io.StringIO()
    for i in progress_bar(range(2), desc="fit", stream=log):
        note(f"check {i}", stream=log)
        note("hidden", stream=log, enabled=False)
    assert [line.split(" in ")[0] for line in log.getvalue().splitlines()] == [
        "check 0",
        "fit: 1/2",
        "check 1",
        "fit: 2/2",
    ]


def test_a_terminal_gets_a_redrawn_bar() -> None:
    screen = _Terminal()
    assert list(progress_bar(range(20), desc="bar", stream=screen)) == list(range(20))
    assert "\r" in screen.getvalue() and "20/20" in screen.getvalue()


def test_a_stage_run_into_a_file_logs_lines_not_bars(tmp_path) -> None:
    code = (
        "from metadagger.utils.progress import note, progress_bar\n"
        "for _ in progress_bar(range(1000), desc='seeds'):\n"
        "    for _ in progress_bar(range(10), desc='inner', leave=False): pass\n"
    )
    with open(tmp_path / "log.txt", "w") as log:
        subprocess.run([sys.executable, "-c", code], stderr=log, check=True)
    text = (tmp_path / "log.txt").read_text()
    assert "\r" not in text and len(text.splitlines()) == 4
