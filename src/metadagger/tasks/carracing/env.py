"""``metadagger/CarRacing-v0``: upstream's CarRacing with a fast state renderer."""

from __future__ import annotations

import numpy as np
from gymnasium.envs.box2d.car_racing import CarRacing
from gymnasium.utils import EzPickle

from metadagger.errors import UserError
from metadagger.tasks.carracing.render import StateRenderer

RENDERERS = ("fast", "reference")


class CarRacingFast(CarRacing):
    """
    ## Description
    Gymnasium's ``CarRacing-v3`` (top-down racing on a random track, from pixels) with the same
    track generation, physics, rewards and termination: this class subclasses upstream's env
    and only replaces how the 96x96 state image is drawn. Upstream draws ~700 polygons with
    pygame at 1000x800 and downscales; here the state is drawn directly at 96x96 with OpenCV
    (a map of the track drawn once per episode and sampled each frame, the car filled on top;
    see :mod:`metadagger.tasks.carracing.render`), many times faster and within a grey level of
    upstream's image on average.

    ## Action Space
    As upstream. If continuous, ``Box([-1, 0, 0], [1, 1, 1])``: steering (-1 full left,
    +1 full right), gas, brake. If discrete, ``Discrete(5)``: do nothing, right, left, gas, brake.

    ## Observation Space
    A top-down 96x96x3 ``uint8`` RGB image of the car and the track, with upstream's indicator
    bar at the bottom (true speed, four ABS sensors, steering wheel position, gyroscope) and
    the running reward.

    ## Rewards
    -0.1 every frame and +1000/N for every track tile visited, where N is the number of tiles;
    -100 (replacing the frame's reward) for leaving the playfield.

    ## Starting State
    The car starts at rest in the centre of the road; the camera zooms in during the first
    second.

    ## Episode Termination
    When all tiles are visited (a lap of ``lap_complete_percent`` of the track), or when the car
    leaves the playfield. The registered id truncates after 1000 steps.

    ## Arguments
    ```python
    >>> import gymnasium as gym, metadagger
    >>> env = gym.make("metadagger/CarRacing-v0", render="fast", lap_complete_percent=0.95)
    ```
    * ``render="fast"``: how the state image is drawn: ``"fast"`` (OpenCV) or
      ``"reference"`` (upstream's pygame renderer, for comparisons).
    * ``render_mode``, ``verbose``, ``lap_complete_percent``, ``domain_randomize``,
      ``continuous``: as upstream. ``render_mode="rgb_array"``/``"human"`` use upstream's
      renderer (they are for people, not for the learner).
    """

    def __init__(
        self,
        *,
        render_mode: str | None = None,
        verbose: bool = False,
        lap_complete_percent: float = 0.95,
        domain_randomize: bool = False,
        continuous: bool = True,
        render: str = "fast",
    ):
        if render not in RENDERERS:
            raise UserError(
                f"render={render!r} is not supported: expected one of {', '.join(map(repr, RENDERERS))}; pass "
                "render='fast' or render='reference'"
            )
        super().__init__(
            render_mode=render_mode,
            verbose=verbose,
            lap_complete_percent=lap_complete_percent,
            domain_randomize=domain_randomize,
            continuous=continuous,
        )
        # Upstream records its arguments positionally; record ours (keyword-only) instead.
        EzPickle.__init__(
            self,
            render_mode=render_mode,
            verbose=verbose,
            lap_complete_percent=lap_complete_percent,
            domain_randomize=domain_randomize,
            continuous=continuous,
            render=render,
        )
        self.render_kind = render
        self._renderer = StateRenderer()
        self._rendered_car = None
        self._road_vertices = np.zeros((0, 4, 2))
        self._road_colors = np.zeros((0, 3))

    def _create_track(self) -> bool:
        if not super()._create_track():
            return False
        # One (P, 3) colour array for every road polygon; each tile's ``color`` becomes a view
        # into it, so the contact listener's in-place recolouring (``tile.color[:] = ...``)
        # reaches both upstream's ``road_poly`` and the fast renderer without any bookkeeping.
        self._road_vertices = np.array([poly for poly, _ in self.road_poly], dtype=np.float64)
        self._road_colors = np.array([color for _, color in self.road_poly], dtype=np.float64)
        tiles = iter(self.road)
        for j, (poly, color) in enumerate(self.road_poly):
            if isinstance(color, np.ndarray):  # tiles carry arrays, kerbs constant tuples
                tile = next(tiles)
                tile.color = self._road_colors[j]
                self.road_poly[j] = (poly, tile.color)
        return True

    def _render(self, mode: str):
        if mode != "state_pixels" or self.render_kind == "reference":
            return super()._render(mode)
        if "t" not in self.__dict__:
            return None  # reset() not called yet, as upstream
        if self._rendered_car is not self.car:  # a reset built a new track and car
            self._renderer.reset(
                road_vertices=self._road_vertices,
                road_colors=self._road_colors,
                bg_color=self.bg_color,
                grass_color=self.grass_color,
                car=self.car,
            )
            self._rendered_car = self.car
        return self._renderer.render(t=self.t, reward=self.reward)
