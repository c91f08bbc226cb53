"""Unit tests of the fast CarRacing renderer's pieces (geometry, text, indicator bars)."""

from __future__ import annotations

import numpy as np
import pytest

from metadagger.tasks.carracing import indicators
from metadagger.tasks.carracing.indicators import text_patch
from metadagger.tasks.carracing.render import STATE_SIZE, StateRenderer, miters


def rectangle(w: float, h: float, clockwise: bool = False) -> np.ndarray:
    pts = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=np.float64)
    return pts[::-1].copy() if clockwise else pts


@pytest.mark.parametrize("clockwise", [False, True])
def test_miters_shrink_a_rectangle_evenly(clockwise):
    poly = rectangle(10, 4, clockwise)[None]
    m, limit = miters(poly, np.ones(4))
    shrunk = poly + 0.5 * m
    assert np.allclose(shrunk.min(axis=1), [0.5, 0.5])
    assert np.allclose(shrunk.max(axis=1), [9.5, 3.5])
    assert limit[0] == pytest.approx(2.0)  # half the short side


def test_miters_with_zero_weight_keep_those_edges():
    poly = rectangle(10, 4)[None]
    # edges 1 and 3 are the vertical sides (x = 10 and x = 0): only they move
    m, limit = miters(poly, np.array([0.0, 1.0, 0.0, 1.0]))
    shrunk = poly + 1.0 * m
    assert np.allclose(shrunk[0, :, 1], poly[0, :, 1])
    assert np.allclose(sorted(set(shrunk[0, :, 0])), [1.0, 9.0])
    assert limit[0] == pytest.approx(5.0)


def test_text_patch_is_a_cached_readonly_corner():
    patch = text_patch("0123")
    assert patch.shape == (12, 12, 3) and patch.dtype == np.uint8
    assert patch.max() > 100  # white digits on black
    assert not patch.flags.writeable
    assert text_patch("0123") is patch
    assert not np.array_equal(text_patch("0999"), patch)


def test_bar_patch_covers_its_area():
    # pygame fills x 125..150 and y 760..780 inclusive: 26 x 21 screen pixels
    r, c, pixels = indicators._bar_patch(125, 150, 760, 780, (255, 255, 255))
    covered = pixels[..., 0].astype(float).sum() / 255
    assert covered == pytest.approx(26 * 21 * (96 / 1000) * (96 / 800), abs=0.5 * pixels[..., 0].size / 255 + 1e-9)
    assert c == 12 and r == int((760 - 700) * 96 / 800)


def test_bar_patch_outside_the_strip_is_none():
    assert indicators._bar_patch(125, 150, 600, 650, (255, 255, 255)) is None
    assert indicators._bar_patch(1100, 1200, 720, 760, (255, 0, 0)) is None


def test_renderer_rejects_bad_supersample_and_render_before_reset():
    with pytest.raises(ValueError, match="supersample"):
        StateRenderer(supersample=3)
    with pytest.raises(RuntimeError, match="reset"):
        StateRenderer().render(t=0.0, reward=0.0)


def test_renderer_reset_checks_shapes():
    with pytest.raises(ValueError, match="road_vertices"):
        StateRenderer().reset(
            road_vertices=np.zeros((3, 3, 2)),
            road_colors=np.zeros((3, 3)),
            bg_color=np.zeros(3),
            grass_color=np.zeros(3),
            car=None,
        )
    assert STATE_SIZE == 96


def test_text_survives_pygame_quit():
    import pygame

    text_patch("0042")
    pygame.quit()  # what upstream's close() does after a human render
    assert text_patch("0043").max() > 100


def test_touched_tiles_repaint_the_map_as_a_fresh_draw_would():
    import gymnasium as gym

    import metadagger

    task = metadagger.make_task("carracing")
    env = gym.make("metadagger/CarRacing-v0")
    try:
        env.reset(seed=3)
        renderer = env.unwrapped._renderer

        def colours() -> np.ndarray:  # the map holds palette indices; a fresh draw may number them otherwise
            return renderer._palette[0][renderer._map]

        before = colours()
        for _ in range(150):  # the expert drives over ~40 tiles, each recoloured on contact
            env.step(task.expert(env))
        repainted = colours()
        assert not np.array_equal(before, repainted)
        renderer._draw_map()
        np.testing.assert_array_equal(repainted, colours())
    finally:
        env.close()
