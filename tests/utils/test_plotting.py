"""Error bars from intervals, and a figure that fails costing only itself."""

from __future__ import annotations

import pytest

from metadagger.imitation.metrics import wilson_interval
from metadagger.utils.plotting import draw_figure, interval_errors, plt, save_figure


def _counts() -> list[tuple[int, int]]:
    """(k, n) for every n in 1..200: none and all succeed, and a few in between."""
    return sorted({(k, n) for n in range(1, 201) for k in (0, 1, n // 3, n // 2, n - 1, n) if 0 <= k <= n})


def test_wilson_error_bars_are_never_negative():
    pairs = _counts()
    rates = [k / n for k, n in pairs]
    bounds = [wilson_interval(k, n) for k, n in pairs]
    below, above = interval_errors(rates, [lo for lo, _ in bounds], [hi for _, hi in bounds])
    assert len(below) == len(above) == len(pairs)
    assert min(below) >= 0.0 and min(above) >= 0.0
    for (k, n), b, a in zip(pairs, below, above):
        assert (b == 0.0) == (k == 0) and (a == 0.0) == (k == n), (k, n, b, a)
    fig, ax = plt.subplots()
    ax.errorbar(range(len(pairs)), rates, yerr=[below, above])  # matplotlib refuses a negative yerr
    plt.close(fig)


def test_a_bound_a_rounding_error_beyond_its_centre_is_on_it():
    # a summary written before wilson_interval clamped: 0/2's low bound a hair above 0
    assert interval_errors([0.0, 1.0], [1e-17, 0.2], [0.66, 1.0 - 1e-16]) == [[0.0, 0.8], [0.66, 0.0]]


def test_an_interval_without_its_centre_is_an_error():
    with pytest.raises(ValueError, match=r"interval \[0.3, 0.9\] does not hold its centre 0.2"):
        interval_errors([0.2], [0.3], [0.9])
    with pytest.raises(ValueError, match="as many lows and highs as centres, got 2, 1, 2"):
        interval_errors([0.2, 0.3], [0.1], [0.4, 0.5])


def test_a_figure_that_fails_is_one_warning_line_and_leaves_no_figure_open(tmp_path, capsys):
    def broken(path):
        plt.subplots()
        raise RuntimeError("no ink\nsecond line")

    path = tmp_path / "f.png"
    assert draw_figure(path, broken) == "RuntimeError: no ink second line"
    assert capsys.readouterr().err == f"warning: figure {path} was not drawn (RuntimeError: no ink second line)\n"
    assert plt.get_fignums() == [] and not path.exists()


def test_a_figure_that_draws_returns_none(tmp_path, capsys):
    def fine(path):
        fig, ax = plt.subplots()
        ax.plot([1, 2], [3, 4])
        save_figure(fig, path)

    assert draw_figure(tmp_path / "f.png", fine) is None
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG" and capsys.readouterr().err == ""
