"""CarRacing's indicator strip as upstream draws it: the speed, ABS, steering and gyro bars and the
running reward along the bottom of the 96x96 state, each from a cached, area-averaged patch.

The strip is drawn on the state itself, after the picture above it is downscaled: upstream's bars
and text are whole screen pixels, so each distinct bar or string is averaged once and reused.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from gymnasium.envs.box2d import car_dynamics as cd
from gymnasium.envs.box2d import car_racing as cr

STATE_SIZE = cr.STATE_W  # the state is square: 96x96
SX = STATE_SIZE / cr.WINDOW_W  # state pixels per upstream screen pixel, horizontally
SY = STATE_SIZE / cr.WINDOW_H  # ... and vertically
#: Upstream's indicator bar: the bottom 5/40 of the screen; one indicator slot is W/40 x H/40.
BAR_TOP = cr.WINDOW_H - 5 * cr.WINDOW_H / 40.0
_SLOT_W = cr.WINDOW_W / 40.0
_SLOT_H = cr.WINDOW_H / 40.0
#: The reward text sits left of the first indicator slot (x < 5 slots); its cached patch covers
#: that corner of the bar, exactly 12x12 state pixels.
_TEXT_BOX = (int(5 * _SLOT_W), int(cr.WINDOW_H - BAR_TOP))  # (width, height) in screen pixels
_TEXT_PATCH = (round(_TEXT_BOX[0] * SX), round(_TEXT_BOX[1] * SY))
_TEXT_CENTER = (60, cr.WINDOW_H - cr.WINDOW_H * 2.5 / 40.0)


@functools.lru_cache(maxsize=8192)
def text_patch(text: str) -> np.ndarray:
    """The reward text as upstream draws it, area-downscaled to its 12x12 corner of the state.

    Rendered with pygame once per distinct string (upstream's font, size and centre) onto the
    black bar, then area-averaged like the rest of the screen.
    """
    import pygame

    surface = _render_text(text)
    glyphs = np.transpose(pygame.surfarray.array3d(surface), (1, 0, 2))
    rect = surface.get_rect()
    rect.center = _TEXT_CENTER
    box = np.zeros((_TEXT_BOX[1], _TEXT_BOX[0], 3), dtype=np.uint8)
    x, y = rect.x, rect.y - int(BAR_TOP)
    # clip like a blit would (long strings run past the box)
    gx0, gy0 = max(-x, 0), max(-y, 0)
    x0, y0 = max(x, 0), max(y, 0)
    h = min(glyphs.shape[0] - gy0, box.shape[0] - y0)
    w = min(glyphs.shape[1] - gx0, box.shape[1] - x0)
    box[y0 : y0 + h, x0 : x0 + w] = glyphs[gy0 : gy0 + h, gx0 : gx0 + w]
    patch = cv2.resize(box, _TEXT_PATCH, interpolation=cv2.INTER_AREA)
    patch.setflags(write=False)
    return patch


@functools.lru_cache(maxsize=1)
def warm_text_patches() -> None:
    """Render the reward text of every whole reward an episode can show, once per process
    (about 0.1 s): a rollout then never stops to draw text, which costs ~80 us per new string."""
    for value in range(_REWARD_RANGE[0], _REWARD_RANGE[1] + 1):
        text_patch(f"{value:04.0f}")


#: Rewards shown on screen: -0.1 a step for up to 1000 steps (-100 more on leaving the playfield)
#: up to +1000 for a full lap.
_REWARD_RANGE = (-200, 1000)


def _render_text(text: str):
    """``text`` as upstream renders it (white on black, its font and size), as a pygame surface.

    ``pygame.quit()`` (upstream's ``close()``) invalidates loaded fonts, even after a later
    ``pygame.font.init()``; the font is then loaded again.
    """
    import pygame

    font = _FONT_CACHE.get("font")
    if font is not None:
        try:
            return font.render(text, True, (255, 255, 255), (0, 0, 0))
        except pygame.error:
            pass
    pygame.font.init()
    _FONT_CACHE["font"] = pygame.font.Font(pygame.font.get_default_font(), 42)
    return _FONT_CACHE["font"].render(text, True, (255, 255, 255), (0, 0, 0))


_FONT_CACHE: dict = {}


def draw_indicators(state: np.ndarray, car: cd.Car, reward: float) -> None:
    """Speed, ABS, steering and gyro bars and the running ``reward`` on the (black) indicator strip
    of the 96x96 ``state``, in place.

    pygame fills whole screen pixels from a bar's truncated low to its truncated high corner,
    so a bar's look depends only on those integers: each distinct bar is area-averaged once
    (:func:`_bar_patch`) and cached. Bars do not overlap (adjacent ABS bars share one screen
    pixel column), so they are painted with ``max``. A bar is clipped to the strip; upstream's
    would run into the picture only beyond |omega| = 400 rad/s (a car under full gas peaks
    near 200). Whole strips are not cached: the speed and wheel bars change almost every
    frame, so such a cache hit 3% of frames.
    """
    vx, vy = car.hull.linearVelocity
    wheels = car.wheels
    speed = math.sqrt(vx * vx + vy * vy)
    strip = state[STATE_SIZE - _STRIP_ROWS :]
    strip.fill(0)
    for value, (scale, x0, x1, color) in zip((speed, *(w.omega for w in wheels)), _V_BARS):
        if abs(value) > 1e-4:
            y = int(_V_BOTTOM + scale * value)  # pygame truncates, then fills both ends
            _paint(strip, _bar_patch(x0, x1, min(y, _V_BOTTOM_PX), max(y, _V_BOTTOM_PX), color))
    for value, (scale, start, color) in zip((wheels[0].joint.angle, car.hull.angularVelocity), _H_BARS):
        if abs(value) > 1e-4:
            x = int(start + scale * value)
            _paint(strip, _bar_patch(min(x, int(start)), max(x, int(start)), _H_TOP, _H_BOTTOM, color))
    state[STATE_SIZE - _TEXT_PATCH[1] :, : _TEXT_PATCH[0]] = text_patch(f"{reward:04.0f}")


def _paint(strip: np.ndarray, patch: tuple[int, int, np.ndarray] | None) -> None:
    if patch is not None:
        r, c, pixels = patch
        roi = strip[r : r + pixels.shape[0], c : c + pixels.shape[1]]
        np.maximum(roi, pixels, out=roi)


# Upstream's indicators in screen pixels: speed and the four ABS sensors are vertical bars in
# slots 5 and 7-10 rising from y = H - H/40 by H/40 * k * value; steering and gyroscope are
# horizontal bars in rows 2-4 (from the bottom) starting at slots 20 and 30, W/40 * k * value
# long. Rows: (screen pixels per unit of value, x0, x1, colour) and (..., start x, colour).
_V_BOTTOM = cr.WINDOW_H - _SLOT_H
_V_BOTTOM_PX = int(_V_BOTTOM)
_V_BARS = tuple(
    (-_SLOT_H * k, int(p * _SLOT_W), int((p + 1) * _SLOT_W), c)
    for k, p, c in (
        (0.02, 5, (255, 255, 255)),
        (0.01, 7, (0, 0, 255)),
        (0.01, 8, (0, 0, 255)),
        (0.01, 9, (51, 0, 255)),
        (0.01, 10, (51, 0, 255)),
    )
)
_H_TOP, _H_BOTTOM = int(cr.WINDOW_H - 4 * _SLOT_H), int(cr.WINDOW_H - 2 * _SLOT_H)
_H_BARS = ((-10.0 * _SLOT_W, 20 * _SLOT_W, (0, 255, 0)), (-0.8 * _SLOT_W, 30 * _SLOT_W, (255, 0, 0)))
_STRIP_ROWS = round((cr.WINDOW_H - BAR_TOP) * SY)  # the indicator strip's height in state rows


@functools.lru_cache(maxsize=8192)
def _bar_patch(x0: int, x1: int, y0: int, y1: int, color: tuple[int, int, int]) -> tuple[int, int, np.ndarray] | None:
    """A bar pygame fills from screen pixel (x0, y0) to (x1, y1), both included, clipped to the
    strip and area-averaged: its first strip row and column and its (h, w, 3) pixels, or None."""
    x0, x1 = max(x0, 0), min(x1 + 1, cr.WINDOW_W)
    y0, y1 = max(y0, int(BAR_TOP)), min(y1 + 1, cr.WINDOW_H)
    if x1 <= x0 or y1 <= y0:
        return None
    c0, cols = _coverage(x0 * SX, x1 * SX)
    r0, rows = _coverage((y0 - BAR_TOP) * SY, (y1 - BAR_TOP) * SY)
    pixels = np.rint(rows[:, None, None] * cols[None, :, None] * np.array(color, dtype=np.float64)).astype(np.uint8)
    pixels.setflags(write=False)
    return r0, c0, pixels


def _coverage(lo: float, hi: float) -> tuple[int, np.ndarray]:
    """First pixel and the fractions of pixels first, first+1, ... covered by [lo, hi)."""
    first = int(math.floor(lo))
    idx = np.arange(first, int(math.ceil(hi)), dtype=np.float64)
    return first, np.minimum(idx + 1, hi) - np.maximum(idx, lo)
