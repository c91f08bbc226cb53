"""The CarRacing expert: pure-pursuit steering and a proportional speed controller.

The expert is *stateless*: its action is a pure function of the simulator state it reads from
``env.unwrapped`` (track centre line, car position, heading, velocity, wheel spin). DAgger asks it
to label arbitrary states the learner drives into, so it must not depend on a history it did not
see. The only thing it keeps is a per-track cache of precomputed arrays (centre line, arc length,
speed profile), stored on the env and keyed on the identity of the track object, so a new track
after ``reset`` is picked up automatically.

Steering (lateral control): pure pursuit on the track centre line. The look-ahead point lies
``lookahead_base + lookahead_per_speed * speed`` ahead (along the track) of the point nearest the
rear axle; the front-wheel angle that puts the rear axle on a circle through that point is
``atan(wheelbase * 2 sin(alpha) / distance)``. The env turns the wheels towards ``-action[0]``
radians (limit +-0.4 rad), so the action is that angle with its sign flipped.

Speed (longitudinal control): a speed profile per track, ``sqrt(lateral_accel / |curvature|)``
in corners, limited backwards along the track so the car can brake in time at ``brake_decel``.
Gas and brake are proportional to the speed error. Recovery: off the tarmac, far from the track
or pointing away from it the target speed drops; gas is cut while the rear wheels spin.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, fields
from typing import Any

import gymnasium as gym
import numpy as np

#: Front-wheel joint limit of ``gymnasium.envs.box2d.car_dynamics`` (radians).
STEER_LIMIT = 0.4
#: Distance from the rear axle to the front axle (car_dynamics WHEELPOS, SIZE = 0.02).
WHEELBASE = (80 + 82) * 0.02
#: Distance from the hull origin back to the rear axle.
REAR_AXLE = 82 * 0.02
#: Wheel radius (car_dynamics WHEEL_R * SIZE).
WHEEL_RADIUS = 27 * 0.02
#: Half the tarmac width (car_racing TRACK_WIDTH = 40 / SCALE).
TRACK_HALF_WIDTH = 40 / 6.0

#: Track points ahead whose speed limit already applies: covers the lag of throttle and brakes.
SPEED_PREVIEW = 4

_CACHE_ATTR = "_metadagger_pid_track"


@dataclass(frozen=True)
class PIDExpertConfig:
    """Gains and limits of :class:`PIDExpert` (world units and seconds)."""

    lookahead_base: float = 6.0
    """Look-ahead distance at standstill."""
    lookahead_per_speed: float = 0.25
    """Extra look-ahead per unit of speed (seconds)."""
    lateral_accel: float = 200.0
    """Lateral acceleration allowed in corners; sets the corner speed limit."""
    brake_decel: float = 30.0
    """Deceleration assumed when planning braking before a corner."""
    max_speed: float = 120.0
    """Speed limit on straights."""
    offtrack_speed: float = 40.0
    """Speed limit with the car's rear axle off the tarmac."""
    free_turn: float = math.pi / 6
    """Angle to the target (radians) up to which the speed is not lowered."""
    turn_speed: float = 20.0
    """Speed kept while turning to face the target (pointing away from it lowers the target speed)."""
    gas_gain: float = 0.1
    """Gas per unit of speed below the target."""
    brake_gain: float = 0.05
    """Brake per unit of speed above the target."""
    max_brake: float = 0.8
    """Largest brake (>= 0.9 locks the wheels in car_dynamics)."""
    max_wheel_slip: float = 5.0
    """Rear-wheel surface speed above the forward speed at which gas is cut."""
    curvature_window: int = 3
    """Half-width (in track points) of the window curvature is measured over."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "curvature_window":
                if not isinstance(value, int) or value < 1:
                    raise ValueError(f"curvature_window must be an int >= 1, got {value!r}")
            elif f.name == "max_brake":
                if not 0.0 < value < 0.9:
                    raise ValueError(f"max_brake must be in (0, 0.9), got {value!r}")
            elif f.name == "lookahead_per_speed":
                if value < 0:
                    raise ValueError(f"lookahead_per_speed must be >= 0, got {value!r}")
            elif not value > 0:
                raise ValueError(f"{f.name} must be > 0, got {value!r}")


@dataclass(frozen=True)
class TrackGeometry:
    """Arrays precomputed once per track (index i = track tile i)."""

    points: np.ndarray
    """(N, 2) centre-line points."""
    tangents: np.ndarray
    """(N, 2) unit direction of travel at each point."""
    arc: np.ndarray
    """(N,) arc length from point 0."""
    length: float
    """Length of one lap."""
    speed_limit: np.ndarray
    """(N,) target speed at each point (corner limit, limited for braking in time)."""
    arcs: list[float]
    """:attr:`arc` as Python floats (the per-step lookups)."""
    speed_limits: list[float]
    """:attr:`speed_limit` as Python floats."""


def track_geometry(track: list[tuple[float, float, float, float]], config: PIDExpertConfig) -> TrackGeometry:
    """Precompute the centre line, arc length and speed profile of a CarRacing track.

    Args:
        track: ``env.unwrapped.track``, a list of ``(alpha, beta, x, y)`` per tile.
        config: gives the corner and braking accelerations.
    """
    points = np.asarray(track, dtype=np.float64)[:, 2:4]
    step = np.roll(points, -1, axis=0) - points
    seg = np.linalg.norm(step, axis=1)
    tangents = step / seg[:, None]
    arc = np.concatenate([[0.0], np.cumsum(seg[:-1])])
    heading = np.unwrap(np.arctan2(tangents[:, 1], tangents[:, 0]))
    # The track is a closed loop: extend the unwrapped heading by one lap turn on each side so the
    # centred difference is valid at the seam.
    n, k = len(points), config.curvature_window
    turn = heading[-1] - heading[0] + _wrap(heading[0] - heading[-1])
    ext = np.concatenate([heading[-k:] - turn, heading, heading[:k] + turn])
    curvature = np.abs(ext[2 * k :] - ext[: -2 * k]) / (2 * k * seg.mean())
    limit = np.minimum(np.sqrt(config.lateral_accel / np.maximum(curvature, 1e-9)), config.max_speed)
    # Limit backwards along the loop (twice round so the seam is covered): v_i^2 <= v_{i+1}^2 + 2 a ds.
    for _ in range(2):
        for i in range(n - 1, -1, -1):
            nxt = limit[(i + 1) % n]
            limit[i] = min(limit[i], math.sqrt(nxt * nxt + 2.0 * config.brake_decel * seg[i]))
    return TrackGeometry(
        points=points,
        tangents=tangents,
        arc=arc,
        length=float(seg.sum()),
        speed_limit=limit,
        arcs=arc.tolist(),
        speed_limits=limit.tolist(),
    )


def _wrap(angle: float | np.ndarray) -> Any:
    """Angle wrapped into [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


class PIDExpert:
    """Stateless CarRacing expert: ``expert(env)`` -> ``[steer, gas, brake]`` (float32).

    Works on any env whose ``unwrapped`` is gymnasium's ``CarRacing`` (``CarRacing-v3``) or a
    subclass of it, after ``reset``.
    """

    def __init__(self, *, config: PIDExpertConfig | None = None):
        self.config = config or PIDExpertConfig()

    def geometry(self, env: gym.Env) -> TrackGeometry:
        """The cached :class:`TrackGeometry` of ``env``'s current track."""
        base = env.unwrapped
        track = getattr(base, "track", None)
        if track is None or getattr(base, "car", None) is None:
            raise RuntimeError("the CarRacing expert needs an env that has been reset (no track or car yet)")
        cached = getattr(base, _CACHE_ATTR, None)
        if cached is None or cached[0] is not track or cached[1] != self.config:
            cached = (track, self.config, track_geometry(track, self.config))
            setattr(base, _CACHE_ATTR, cached)
        return cached[2]

    def __call__(self, env: gym.Env) -> np.ndarray:
        # Two-vectors are Python floats: numpy's call overhead on them was most of the cost. Each
        # product, sum and dot product is the same IEEE operation as numpy's, in the same order, so
        # the labels are bit-equal to the array form's (tests/tasks/carracing/test_expert.py).
        cfg = self.config
        geo = self.geometry(env)
        car = env.unwrapped.car
        angle = car.hull.angle + 0.5 * math.pi  # the hull's forward axis is its local +y
        fx, fy = math.cos(angle), math.sin(angle)
        lx, ly = -fy, fx
        vx, vy = car.hull.linearVelocity
        speed = float(np.hypot(vx, vy))
        px, py = car.hull.position
        rx, ry = px - REAR_AXLE * fx, py - REAR_AXLE * fy

        # Localise: nearest centre-line point, then the projection onto its segment.
        offsets = np.array([rx, ry]) - geo.points
        i = int(np.argmin(np.einsum("ij,ij->i", offsets, offsets)))
        ox, oy = offsets[i].tolist()
        tx, ty = geo.tangents[i].tolist()
        along = ox * tx + oy * ty
        lateral = abs(ox * -ty + oy * tx)
        s_here = float(geo.arc[i]) + along

        # Steering: pure pursuit towards the point `lookahead` further along the track. Far from the
        # track the target is far away too; capping the distance at the look-ahead keeps the turn
        # as sharp as it would be on the track, so the car heads back instead of drifting away.
        lookahead = cfg.lookahead_base + cfg.lookahead_per_speed * speed
        qx, qy = self._point_at(geo, s_here + lookahead)
        dx, dy = qx - rx, qy - ry
        alpha = math.atan2(dx * lx + dy * ly, dx * fx + dy * fy)
        dist = min(float(np.hypot(dx, dy)), lookahead)
        wheel = math.atan(WHEELBASE * 2.0 * math.sin(alpha) / dist)
        if abs(alpha) > 0.5 * math.pi:  # target behind: full lock towards it
            wheel = math.copysign(STEER_LIMIT, alpha)
        steer = _clip(-wheel, -1.0, 1.0)

        # Speed: the profile here and a little ahead; lower off the tarmac, and lower when the car
        # must turn more than `free_turn` to face its target (never below `turn_speed`, so it
        # keeps moving). Normal cornering needs less than `free_turn` and is not slowed.
        n = len(geo.points)
        v_target = min(geo.speed_limits[(i + k) % n] for k in range(SPEED_PREVIEW))
        if lateral > TRACK_HALF_WIDTH:
            v_target = min(v_target, cfg.offtrack_speed)
        excess = max(abs(alpha) - cfg.free_turn, 0.0)
        v_target = min(v_target, max(v_target * math.cos(min(excess, 0.5 * math.pi)), cfg.turn_speed))
        gas = _clip(cfg.gas_gain * (v_target - speed), 0.0, 1.0)
        brake = _clip(cfg.brake_gain * (speed - v_target), 0.0, cfg.max_brake)
        forward_speed = vx * fx + vy * fy
        spin = max(w.omega * WHEEL_RADIUS for w in car.wheels[2:4]) - forward_speed
        if spin > cfg.max_wheel_slip:
            gas = 0.0
        return np.array([steer, gas, brake], dtype=np.float32)

    @staticmethod
    def _point_at(geo: TrackGeometry, s: float) -> tuple[float, float]:
        """Centre-line point at arc length ``s`` (wrapping round the loop), linearly interpolated."""
        s = s % geo.length
        j = bisect.bisect_right(geo.arcs, s) - 1
        nxt = (j + 1) % len(geo.points)
        (x0, y0), (x1, y1) = geo.points[j].tolist(), geo.points[nxt].tolist()
        sx, sy = x1 - x0, y1 - y0
        t = (s - geo.arcs[j]) / float(np.hypot(sx, sy))
        return x0 + sx * t, y0 + sy * t


def _clip(value: float, low: float, high: float) -> float:
    """``value`` limited to ``[low, high]`` (``np.clip`` of one float)."""
    return min(max(value, low), high)
