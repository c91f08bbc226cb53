"""What a person needs of a state that its frame lacks: an overview drawn from the env's own state.

CarRacing's frame shows a few car lengths around the car; off the road it shows only grass, and
nothing says where the road went. Its overview (:class:`TrackOverview`) is the whole track from
above with the car's place and heading. A task declares its own with a method
``person_overview(self) -> Overview``; a task that declares none gets the packaged one where there
is one (:func:`overview_of`), else no overview. The packaged one is kept here, not in the task's
package, for the reason :mod:`metadagger.label.forms` gives.

While a person labels, the session's env is wrapped by an :class:`OverviewRecorder`, which keeps
a small snapshot of each state the learner visits (:meth:`Overview.snapshot`); the overview of the
state asked is drawn from them when the page asks for it (:meth:`Overview.draw`).
"""

from __future__ import annotations

import abc
import functools
import math
from typing import Any, Callable, Sequence, SupportsFloat

import cv2
import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.imitation.rollouts import Trajectory
from metadagger.tasks.base import Task
from metadagger.tasks.carracing.expert import TRACK_HALF_WIDTH
from metadagger.tasks.carracing.task import CarRacingTask


class Overview(abc.ABC):
    """A picture of a state beside its frame, drawn from snapshots of the env taken as an episode runs."""

    #: What the page says under the picture: what it shows and how to read it.
    caption: str = ""

    @abc.abstractmethod
    def snapshot(self, env: gym.Env) -> Any:
        """What the picture of ``env``'s current state needs, taken after each reset and step; cheap,
        and reading ``env`` only (the episode must not change)."""

    @abc.abstractmethod
    def draw(self, snapshots: Sequence[Any], step: int) -> np.ndarray:
        """The picture (``H x W x 3`` uint8 RGB, or ``H x W`` grey) of ``step`` of an episode whose states gave
        ``snapshots``."""


def overview_of(task: Task) -> Overview | None:
    """The overview a person sees beside ``task``'s frames: its own ``person_overview()``, the packaged
    task's, or None (the page shows the frame alone).

    Raises:
        UserError: the task's ``person_overview()`` returns something else than an :class:`Overview` or None.
    """
    declared = getattr(task, "person_overview", None)
    overview = declared() if callable(declared) else _packaged(task.pistar_task())
    if overview is not None and not isinstance(overview, Overview):
        raise UserError(
            f"task {task.name!r}'s person_overview() must return a metadagger.label.overview.Overview or None, "
            f"got {overview!r}"
        )
    return overview


def _packaged(task: Task) -> Overview | None:
    return TrackOverview() if isinstance(task, CarRacingTask) else None


class OverviewRecorder:
    """The snapshots of every state of the episodes run in an env it wraps (:meth:`wrap`), kept for
    the last episode only: the one whose states a round asks next."""

    def __init__(self, overview: Overview) -> None:
        self.overview = overview
        self._episode: list[Any] = []

    def wrap(self, env: gym.Env) -> gym.Env:
        """``env``, recording a snapshot after its every reset and step."""
        return _Recording(env, self)

    def begin(self, env: gym.Env) -> None:
        """A new episode: its first state's snapshot."""
        self._episode = [self.overview.snapshot(env)]

    def add(self, env: gym.Env) -> None:
        """The snapshot of the state a step led to."""
        self._episode.append(self.overview.snapshot(env))

    def pictures(self, rollout: Trajectory) -> Callable[[int], np.ndarray]:
        """The overview of each step of ``rollout``, the episode recorded last, by step.

        Raises:
            RuntimeError: the last episode recorded is not ``rollout`` (its states number otherwise).
        """
        episode = self._episode
        # one snapshot per acted-on state, and one of the state after the last step
        if len(episode) != rollout.steps + 1:
            raise RuntimeError(
                f"the last episode recorded has {len(episode) - 1} steps, not the {rollout.steps} of the rollout "
                "asked: the rollout was not run in the recorded env"
            )
        return functools.partial(self.overview.draw, episode)


class _Recording(gym.Wrapper):
    """An env that hands itself to an :class:`OverviewRecorder` after each reset and step."""

    def __init__(self, env: gym.Env, recorder: OverviewRecorder) -> None:
        super().__init__(env)
        self._recorder = recorder

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        result = self.env.reset(seed=seed, options=options)
        self._recorder.begin(self.env)
        return result

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        result = self.env.step(action)
        self._recorder.add(self.env)
        return result


#: Colours (RGB) of CarRacing's overview.
_GRASS, _ROAD, _AHEAD, _PATH, _CAR = (88, 150, 88), (105, 105, 105), (250, 250, 250), (255, 150, 0), (220, 0, 0)
#: Fixed-point bits of the vertices handed to OpenCV (sub-pixel lines).
_SHIFT = 4


class TrackOverview(Overview):
    """CarRacing's overview: the whole track from above, turned so that the car heads up as in the frame.

    The car sits in the middle, the scale fits the whole track around it; the road ahead of the
    car's nearest track point (an eighth of the lap) is drawn white, so the direction of the lap is
    plain, and the learner's path up to the state is drawn over the road.

    Args:
        size: the picture's width and height in pixels.
    """

    caption = (
        "The whole track from above, turned so that the car (red) heads up as in the frame: the road ahead of it "
        "is white, the learner's path so far orange."
    )

    def __init__(self, size: int = 224) -> None:
        self.size = size
        self._track: Any = None
        self._line = np.zeros((0, 2))

    def snapshot(self, env: gym.Env) -> tuple[np.ndarray, float, float, float]:
        """The track's centre line (one array per track, shared by its snapshots) and the car's x, y and angle."""
        base = env.unwrapped
        if base.track is not self._track:  # a reset made a new track
            self._track = base.track
            self._line = np.array([(x, y) for _, _, x, y in base.track], dtype=np.float64)
        hull = base.car.hull
        return self._line, float(hull.position[0]), float(hull.position[1]), float(hull.angle)

    def draw(self, snapshots: Sequence[tuple[np.ndarray, float, float, float]], step: int) -> np.ndarray:
        """The overview of ``step``: the track, the road ahead, the path so far and the car."""
        line, x, y, angle = snapshots[step]
        car = np.array([x, y])
        # the car's forward axis (its body's +y) turned onto the picture's up: R(-angle), then y flipped
        c, s = math.cos(angle), math.sin(angle)
        turn = np.array([[c, s], [-s, c]])
        reach = float(np.linalg.norm(line - car, axis=1).max()) + 2 * TRACK_HALF_WIDTH
        half = self.size / 2
        scale = (half - 4) / reach

        def pixels(points: np.ndarray) -> np.ndarray:
            turned = (np.asarray(points, dtype=np.float64).reshape(-1, 2) - car) @ turn.T
            at = np.stack([half + turned[:, 0] * scale, half - turned[:, 1] * scale], axis=1) - 0.5
            return np.rint(at * (1 << _SHIFT)).astype(np.int32)

        image = np.empty((self.size, self.size, 3), dtype=np.uint8)
        image[:] = _GRASS
        road = max(2, round(2 * TRACK_HALF_WIDTH * scale))
        cv2.polylines(image, [pixels(line)], True, _ROAD, road, cv2.LINE_AA, _SHIFT)
        nearest = int(np.argmin(np.linalg.norm(line - car, axis=1)))
        ahead = line[np.arange(nearest, nearest + max(2, len(line) // 8)) % len(line)]
        cv2.polylines(image, [pixels(ahead)], False, _AHEAD, max(1, road // 2), cv2.LINE_AA, _SHIFT)
        path = np.array([(px, py) for _, px, py, _ in snapshots[: step + 1]])
        cv2.polylines(image, [pixels(path)], False, _PATH, 2, cv2.LINE_AA, _SHIFT)
        arrow = np.array([(half, half - 9), (half + 6, half + 7), (half, half + 3), (half - 6, half + 7)]) - 0.5
        arrow = np.rint(arrow * (1 << _SHIFT)).astype(np.int32)
        cv2.fillPoly(image, [arrow], _CAR, cv2.LINE_AA, _SHIFT)
        cv2.polylines(image, [arrow], True, (255, 255, 255), 1, cv2.LINE_AA, _SHIFT)
        return image
