"""Fast 96x96 state renderer for CarRacing, matching upstream's ``state_pixels`` look.

Upstream draws ~700 polygons with pygame at 1000x800 every step and then area-downscales the
surface to 96x96 with ``pygame.transform.smoothscale``. This module draws the state directly:

- **Ground and road** (background, grass squares, road tiles and kerbs) never move, so they are
  drawn once per track into a world map (4 pixels per world unit, about 2.5 per state pixel at
  full zoom). The map holds one byte a pixel, an index into a palette of the track's colours (7
  MB a track instead of 21). Each frame, one ``cv2.warpAffine`` with nearest-neighbour sampling
  gives every canvas pixel the map's index at its centre, and a lookup its colour, which is what
  filling the polygons on the canvas would give. A tile the car touches changes colour
  (upstream's contact listener); it is redrawn on the map, with the parts drawn after it that
  overlap it.
- **Car and indicators** move every frame: the car's polygons go through one vectorised
  transform and OpenCV fills with sub-pixel (fixed-point) vertices; the indicator bars and the
  reward text are cached, area-averaged patches (:mod:`metadagger.tasks.carracing.indicators`).

The canvas is ``supersample`` times the state size, area-downscaled at the end (area averaging is
linear, so this approaches upstream's image). The default ``supersample=1`` keeps the image within
a mean absolute error of about 0.45 of upstream's (0-255 scale).

Coordinates: upstream's screen ("screen pixels", 1000x800) maps onto the 96x96 state
anisotropically (x by 96/1000, y by 96/800). A canvas pixel ``i`` covers ``[i, i+1)``; OpenCV puts
pixel centres on integers, hence the ``-0.5`` in the camera transform (and the map's).

Rasterisation rules differ: OpenCV fills every pixel whose centre lies within half a pixel of a
polygon, pygame every screen pixel between truncated vertices (about half a screen pixel of
growth on each side). Polygons are therefore shrunk by the difference before filling, so their
areas, and hence the averaged colours along edges, match upstream's.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from gymnasium.envs.box2d import car_dynamics as cd
from gymnasium.envs.box2d import car_racing as cr

from metadagger.tasks.carracing.indicators import BAR_TOP, STATE_SIZE, SX, SY, draw_indicators, warm_text_patches

_SHIFT = 8  # fractional bits of the fixed-point vertex coordinates handed to OpenCV
_ONE = float(1 << _SHIFT)
#: Growth of a filled polygon beyond its true outline, measured as (extra area) / perimeter on
#: rotated rectangles: OpenCV's fills grow ~0.48 canvas pixels, pygame's ``gfxdraw`` (ground and
#: road) ~0.48 and ``draw.polygon`` (car) ~0.3 screen pixels. Polygons are shrunk by the
#: difference before filling, so their areas, hence edge colours after averaging, match.
_CV2_GROWTH = 0.48
_GFXDRAW_GROWTH = 0.48
_DRAW_GROWTH = 0.3
#: The world map of the ground and road: pixels per world unit (about 2.5 per canvas pixel at
#: full zoom) and its half-width in world units (the playfield; beyond it all is black).
_MAP_PX = 4.0
_MAP_HALF = cr.PLAYFIELD
_HULL_COLOR = (204, 0, 0)  # upstream draws int(0.8 * 255) for the hull's (0.8, 0, 0)
_WHEEL_COLOR = tuple(int(c * 255) for c in cd.WHEEL_COLOR)
_WHEEL_WHITE = tuple(cd.WHEEL_WHITE)
#: pygame's smoothscale loses two grey levels to fixed-point truncation (measured: a uniform
#: surface of value v comes out as max(v - 2, 0)); applied after our exact area average.
_SMOOTHSCALE_DARKEN = (2.0, 2.0, 2.0, 0.0)  # cv2.subtract saturates at 0
#: Edge weights of road polygons (tiles and kerbs): only the two sides along the track are
#: shrunk; the ends meet the neighbouring tile, so they stay put.
_ALONG_TRACK = np.array([0.0, 1.0, 0.0, 1.0])


def miters(polys: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How convex polygons' vertices move when their edges move inwards, and how far they can.

    Shrinking edge i (vertex i to i+1) inwards by ``d * weights[..., i]`` moves every vertex
    linearly in ``d``: the shrunk polygon is ``polys + d * miters`` until an edge would turn
    around, at ``d = limit``.

    Args:
        polys: (P, V, 2) convex polygons, either orientation.
        weights: (P, V) or (V,) per-edge weights (0 keeps an edge in place).

    Returns:
        (P, V, 2) vertex velocities and the (P,) largest valid ``d``.
    """
    nxt = np.roll(polys, -1, axis=1)
    e = nxt - polys
    cross = (polys[..., 0] * nxt[..., 1] - nxt[..., 0] * polys[..., 1]).sum(axis=1)
    unit = e / np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-12)
    normal = np.stack([-unit[..., 1], unit[..., 0]], axis=-1) * np.where(cross >= 0, 1.0, -1.0)[:, None, None]
    w = np.broadcast_to(weights, polys.shape[:2]).astype(np.float64)
    prev_n, prev_w = np.roll(normal, 1, axis=1), np.roll(w, 1, axis=1)
    # vertex i sits on edges i-1 and i: solve prev_n . m = prev_w and normal . m = w
    det = prev_n[..., 0] * normal[..., 1] - prev_n[..., 1] * normal[..., 0]
    parallel = np.abs(det) < 1e-9
    det = np.where(parallel, 1.0, det)
    m = np.stack(
        [(prev_w * normal[..., 1] - w * prev_n[..., 1]) / det, (prev_n[..., 0] * w - normal[..., 0] * prev_w) / det],
        axis=-1,
    )
    m = np.where(parallel[..., None], normal * w[..., None], m)
    # edge i turns around once d * (m[i+1] - m[i]) . e_i reaches -|e_i|^2
    shrink = np.sum((np.roll(m, -1, axis=1) - m) * e, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):  # the masked-out branch may be 0/0
        limit = np.where(shrink < 0, np.sum(e * e, axis=-1) / -shrink, np.inf).min(axis=1)
    return m, limit


def _ground() -> np.ndarray:
    """Background field then upstream's grass checkerboard (one patch in four cells)."""
    d, f = cr.GRASS_DIM, cr.PLAYFIELD
    field = [[(f, f), (f, -f), (-f, -f), (-f, f)]]
    cells = [(x, y) for x in range(-20, 20, 2) for y in range(-20, 20, 2)]
    grass = [[(d * x + d, d * y), (d * x, d * y), (d * x, d * y + d), (d * x + d, d * y + d)] for x, y in cells]
    return np.array(field + grass, dtype=np.float64)


_GROUND = _ground()


class StateRenderer:
    """Draws CarRacing's 96x96 ``state_pixels`` image from the track arrays and the car's bodies.

    Call :meth:`reset` after every track generation, then :meth:`render` once per step.
    """

    def __init__(self, *, supersample: int = 1):
        if supersample not in (1, 2, 4):
            raise ValueError(f"supersample must be 1, 2 or 4, got {supersample}")
        self.supersample = supersample
        self.size = STATE_SIZE * supersample
        # A 96x96 frame is too small to split across threads: OpenCV's pool made no frame
        # faster, and its idle threads spin (sched_yield) between calls, a third of a core or
        # more per process, taken from the other workers. The setting is process-wide; serial
        # calls give the same pixels (docs/performance.md).
        cv2.setNumThreads(1)
        # Screen pixels -> canvas pixels (geometric mean of the anisotropic x and y scales).
        gain = supersample * math.sqrt(SX * SY)
        self._shrink_car = _CV2_GROWTH - _DRAW_GROWTH * gain  # in canvas pixels
        self._world_per_canvas = 1.0 / gain  # ... times 1 / zoom
        self._canvas = np.zeros((self.size, self.size, 3), dtype=np.uint8)
        self._indices = np.zeros((self.size, self.size), dtype=np.uint8)
        self._map: np.ndarray | None = None
        # the map's colours: index 0 is the black beyond the playfield; (1, 256, 3) for cv2.LUT
        self._palette = np.zeros((1, 256, 3), dtype=np.uint8)
        self._palette_index: dict[tuple[int, ...], int] = {}
        # the canvas point the car sits on: upstream's (W/2, H/4 from the bottom), in canvas pixels
        self._view_centre = (
            cr.WINDOW_W / 2 * SX * supersample - 0.5,
            (cr.WINDOW_H - cr.WINDOW_H / 4) * SY * supersample - 0.5,
        )
        self._car: cd.Car | None = None

    def reset(
        self,
        *,
        road_vertices: np.ndarray,
        road_colors: np.ndarray,
        bg_color: np.ndarray,
        grass_color: np.ndarray,
        car: cd.Car,
    ) -> None:
        """Take a new track and car.

        Args:
            road_vertices: (P, 4, 2) world vertices of every road tile and kerb in draw order,
                each ordered as upstream's (across, along, across, along the track).
            road_colors: (P, 3) colours, kept by reference: in-place recolouring of touched
                tiles (upstream's contact listener) shows up in later frames.
            bg_color: background colour (outside the grass patches).
            grass_color: colour of the grass patches.
            car: upstream's :class:`~gymnasium.envs.box2d.car_dynamics.Car` to draw.
        """
        if road_vertices.ndim != 3 or road_vertices.shape[1:] != (4, 2) or road_colors.shape != (len(road_vertices), 3):
            raise ValueError(
                f"road_vertices must be (P, 4, 2) and road_colors (P, 3), got {road_vertices.shape} and "
                f"{road_colors.shape}"
            )
        # Ground then road, one (S, 4, 2) array, in draw order: they never move, so they are
        # drawn once per track into a world map (see _draw_map), sampled every frame.
        static = np.concatenate([_GROUND, np.asarray(road_vertices, dtype=np.float64)])
        weights = np.concatenate([np.ones((len(_GROUND), 4)), np.tile(_ALONG_TRACK, (len(road_vertices), 1))])
        static_miters, static_limit = miters(static, weights)
        shrink = _CV2_GROWTH / _MAP_PX - _GFXDRAW_GROWTH / (cr.ZOOM * cr.SCALE)  # world units
        # a polygon thinner than twice the shrink is left out (upstream's is below a pixel too)
        self._map_drawn = static_limit > shrink
        self._map_polys = np.rint(((static + shrink * static_miters + _MAP_HALF) * _MAP_PX - 0.5) * _ONE).astype(
            np.int32
        )
        # (S, 4): x0, y0, x1, y1 in map pixels, padded by one for the fills' growth
        lo, hi = (self._map_polys.min(axis=1) >> _SHIFT) - 1, (self._map_polys.max(axis=1) >> _SHIFT) + 2
        self._map_boxes = np.concatenate([lo, hi], axis=1)
        self._n_ground = len(_GROUND)
        self._bg_color = np.asarray(bg_color).astype(np.int32).tolist()
        self._grass_color = np.asarray(grass_color).astype(np.int32).tolist()
        self._road_colors = road_colors
        self._car = car
        self._draw_map()
        warm_text_patches()
        # Body-local car polygons never change during an episode; read them once from Box2D.
        hull = [np.array(f.shape.vertices, dtype=np.float64) for f in car.hull.fixtures]
        ends = np.cumsum([len(p) for p in hull]).tolist()
        self._hull_parts = [slice(start, end) for start, end in zip([0] + ends[:-1], ends)]
        self._hull = np.concatenate(hull)
        self._hull_miters = np.concatenate([miters(p[None], np.ones(len(p)))[0][0] for p in hull])
        wheel = np.array(car.wheels[0].fixtures[0].shape.vertices, dtype=np.float64)
        self._wheel = wheel
        self._wheel_miters = miters(wheel[None], np.ones(4))[0][0]

    def render(self, *, t: float, reward: float) -> np.ndarray:
        """The state image for simulation time ``t`` (camera zoom-in) and the running ``reward``."""
        if self._car is None:
            raise RuntimeError("StateRenderer.render() called before reset()")
        canvas = self._canvas
        zoom = 0.1 * cr.SCALE * max(1 - t, 0) + cr.ZOOM * cr.SCALE * min(t, 1)
        a, b = self._camera(zoom)
        if not np.array_equal(self._road_colors, self._map_colors):  # the car touched a tile
            self._repaint_map(self._n_ground + np.flatnonzero((self._road_colors != self._map_colors).any(axis=1)))
        # each canvas pixel takes the map's colour at its centre, as a fill would
        cv2.warpAffine(
            self._map,
            _canvas_to_map(a, b),
            (self.size, self.size),
            dst=self._indices,
            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        cv2.LUT(cv2.merge((self._indices, self._indices, self._indices)), self._palette, dst=canvas)
        car_polys, car_colors = self._car_polygons(a, b, zoom)
        for poly, col in zip(car_polys, car_colors):
            cv2.fillConvexPoly(canvas, poly, col, cv2.LINE_8, _SHIFT)
        canvas[round(BAR_TOP * SY * self.supersample) :] = 0
        state = canvas
        while state.shape[0] > STATE_SIZE:  # repeated halving is OpenCV's fast area-average path
            state = cv2.resize(state, (state.shape[1] // 2, state.shape[0] // 2), interpolation=cv2.INTER_AREA)
        state = state.copy() if state is canvas else state
        draw_indicators(state, self._car, reward)
        return cv2.subtract(state, _SMOOTHSCALE_DARKEN)

    def _camera(self, zoom: float) -> tuple[np.ndarray, np.ndarray]:
        """Affine map world -> canvas: upstream's rotate/zoom/scroll, the vertical flip, the downscale."""
        car = self._car
        angle = -car.hull.angle
        c, s = math.cos(angle), math.sin(angle)
        sx = SX * self.supersample * zoom
        sy = SY * self.supersample * zoom
        # screen u = zoom*R(angle)(p - pos) + (W/2, H/4); flipped v_y = H - u_y.
        a00, a01, a10, a11 = sx * c, -sx * s, -sy * s, -sy * c
        px, py = car.hull.position
        cx, cy = self._view_centre
        return np.array([[a00, a01], [a10, a11]]), np.array([cx - a00 * px - a01 * py, cy - a10 * px - a11 * py])

    def _draw_map(self) -> None:
        """Draw the ground and road once into the world map, ``_MAP_PX`` pixels per world unit.

        Its polygons are shrunk so that, sampled at canvas pixel centres, they cover what
        upstream's (grown) polygons cover; the map extends to black beyond the playfield.
        """
        if self._map is None:  # one buffer for every track: a fresh one costs page faults
            size = int(math.ceil(2 * _MAP_HALF * _MAP_PX))
            self._map = np.zeros((size, size), dtype=np.uint8)
        else:
            self._map.fill(0)
        self._palette.fill(0)
        self._palette_index = {(0, 0, 0): 0}
        self._map_colors = self._road_colors.copy()
        self._paint_map(np.flatnonzero(self._map_drawn))

    def _repaint_map(self, changed: np.ndarray) -> None:
        """Redraw recoloured road parts (ascending indices into the static polygons) on the map.

        A part covers the same pixels as before. Drawing it again, then every later part that
        reaches into its box, gives what drawing the whole map again would inside that box;
        outside it, a later part may cover a third one, so the map outside the box is restored.
        (Fills are drawn on the whole map: OpenCV rasterises a polygon clipped by an image's
        edge slightly differently.)
        """
        self._map_colors = self._road_colors.copy()
        boxes = self._map_boxes
        for j in changed[self._map_drawn[changed]]:  # a part too thin to draw stays undrawn
            x0, y0, x1, y1 = boxes[j]
            later = boxes[j + 1 :]
            near = (
                self._map_drawn[j + 1 :]
                & (later[:, 0] <= x1)
                & (later[:, 2] >= x0)
                & (later[:, 1] <= y1)
                & (later[:, 3] >= y0)
            )
            indices = np.concatenate([[j], j + 1 + np.flatnonzero(near)])
            (rx0, ry0), (rx1, ry1) = np.maximum(boxes[indices, :2].min(axis=0), 0), boxes[indices, 2:].max(axis=0)
            region = self._map[ry0 : ry1 + 1, rx0 : rx1 + 1]
            saved = region.copy()
            self._paint_map(indices)
            inner = (slice(max(y0, 0) - ry0, y1 + 1 - ry0), slice(max(x0, 0) - rx0, x1 + 1 - rx0))
            saved[inner] = region[inner]
            region[...] = saved

    def _paint_map(self, indices: np.ndarray) -> None:
        """Fill static polygons ``indices`` (ascending: draw order) into the map."""
        image = self._map
        polys = self._map_polys[indices]
        n_ground = int(np.searchsorted(indices, self._n_ground))
        n_background = int(n_ground > 0 and indices[0] == 0)  # _GROUND[0] is the background
        if n_background:
            cv2.fillConvexPoly(image, polys[0], self._index_of(self._bg_color), cv2.LINE_8, _SHIFT)
        if n_ground > n_background:
            # grass squares never overlap, so one call fills them all (its even-odd rule is moot)
            grass = self._index_of(self._grass_color)
            cv2.fillPoly(image, list(polys[n_background:n_ground]), grass, cv2.LINE_8, _SHIFT)
        # int() truncation, as upstream's ``[int(c) for c in color]`` (OpenCV would round).
        colors = self._road_colors[indices[n_ground:] - self._n_ground].astype(np.int32).tolist()
        for poly, color in zip(polys[n_ground:], colors):
            cv2.fillConvexPoly(image, poly, self._index_of(color), cv2.LINE_8, _SHIFT)

    def _index_of(self, color: list[int]) -> int:
        """The map's index of ``color`` (0-255 RGB), added to the palette on first use."""
        key = tuple(color)
        index = self._palette_index.get(key)
        if index is None:
            index = len(self._palette_index)
            if index > 255:
                raise RuntimeError("a CarRacing track uses more than 256 colours; the map holds one byte a pixel")
            self._palette_index[key] = index
            self._palette[0, index] = np.clip(color, 0, 255)
        return index

    def _car_polygons(self, a: np.ndarray, b: np.ndarray, zoom: float) -> tuple[list, list]:
        """Wheels with their rotating stripes, then the hull (upstream's draw order, no particles)."""
        car = self._car
        d = self._shrink_car * self._world_per_canvas / zoom
        bodies = car.wheels + [car.hull]
        pose = np.array([(*body.position, body.angle) for body in bodies])
        cos, sin = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        rot = np.empty((len(bodies), 2, 2))
        rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = cos, -sin, sin, cos
        lin = (a @ rot).transpose(0, 2, 1) * _ONE  # row-vector form: body-local -> fixed-point canvas
        off = (pose[:, :2] @ a.T + b) * _ONE
        # Each wheel as 8 local vertices: its 4 corners, then its stripe's (unused if none).
        stripes = [_stripe(w.phase, d) for w in car.wheels]
        local = np.empty((len(car.wheels), 8, 2))
        local[:, :4] = self._wheel + d * self._wheel_miters
        for i, stripe in enumerate(stripes):
            local[i, 4:] = local[i, :4] if stripe is None else stripe
        wheels = np.rint(np.matmul(local, lin[:-1]) + off[:-1, None]).astype(np.int32)
        hull = np.rint((self._hull + d * self._hull_miters) @ lin[-1] + off[-1]).astype(np.int32)
        polys, colors = [], []
        for pts, stripe in zip(wheels, stripes):
            polys.append(pts[:4])
            colors.append(_WHEEL_COLOR)
            if stripe is not None:
                polys.append(pts[4:])
                colors.append(_WHEEL_WHITE)
        polys.extend(hull[part] for part in self._hull_parts)
        colors.extend([_HULL_COLOR] * len(self._hull_parts))
        return polys, colors


def _canvas_to_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The (2, 3) affine map from canvas pixels to map pixels, given world -> canvas ``a p + b``."""
    (a00, a01), (a10, a11) = a.tolist()
    b0, b1 = b.tolist()
    k = _MAP_PX / (a00 * a11 - a01 * a10)  # map pixels per world unit over det(a)
    i00, i01, i10, i11 = a11 * k, -a01 * k, -a10 * k, a00 * k  # _MAP_PX * inverse(a)
    return np.array(
        [
            [i00, i01, _MAP_HALF * _MAP_PX - 0.5 - i00 * b0 - i01 * b1],
            [i10, i11, _MAP_HALF * _MAP_PX - 0.5 - i10 * b0 - i11 * b1],
        ]
    )


def _stripe(phase: float, shrink: float) -> np.ndarray | None:
    """A wheel's grey stripe at rotation ``phase`` (upstream's rule), wheel-local, shrunk by
    ``shrink`` on every side; None when upstream draws none or it is thinner than that."""
    s1, s2 = math.sin(phase), math.sin(phase + 1.2)
    if s1 > 0 and s2 > 0:
        return None
    c1, c2 = math.cos(phase), math.cos(phase + 1.2)
    if s1 > 0:
        c1 = float((c1 > 0) - (c1 < 0))  # np.sign, as upstream
    if s2 > 0:
        c2 = float((c2 > 0) - (c2 < 0))
    r = cd.WHEEL_R * cd.SIZE
    y1, y2 = min(c1, c2) * r + shrink, max(c1, c2) * r - shrink
    w = cd.WHEEL_W * cd.SIZE - shrink
    if y2 <= y1 or w <= 0:
        return None
    return np.array([(-w, y1), (w, y1), (w, y2), (-w, y2)])
