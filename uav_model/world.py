"""The world the planner sees: obstacles (true and inflated), their motion, the area and geofence.

Everything is in local ENU metres and seconds. Pure: no I/O, no clocks. Obstacle shapes are
shapely geometries at t = 0; a motion model gives the displacement of the whole shape at time t,
vectorised over an array of times so that rollouts can predict moving obstacles in one call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Point, Polygon

ShapeKind = Literal["circle", "rectangle", "triangle", "polygon"]

# Segments per quarter circle when a circle must become a polygon (rasterising, plotting).
# Exact circle queries never use it: see Obstacle.is_circle.
CIRCLE_QUAD_SEGS = 32


@dataclass(frozen=True, slots=True)
class Static:
    """An obstacle that does not move."""

    def offset_at(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return np.zeros(t.shape + (2,))

    def velocity_at(self, t_s: float) -> tuple[float, float]:
        return 0.0, 0.0

    @property
    def is_moving(self) -> bool:
        return False

    @property
    def offset_disc(self) -> tuple[tuple[float, float], float]:
        """A disc (centre, radius) holding every offset the motion ever takes (for culling)."""
        return (0.0, 0.0), 0.0


@dataclass(frozen=True, slots=True)
class Shuttle:
    """Back and forth along a segment: from the shape's start position by ``delta`` and back."""

    delta_m: tuple[float, float]
    speed_m_s: float

    @property
    def is_moving(self) -> bool:
        return self.speed_m_s > 0 and math.hypot(*self.delta_m) > 0

    @property
    def offset_disc(self) -> tuple[tuple[float, float], float]:
        """A disc (centre, radius) holding every offset the motion ever takes: the segment's."""
        return (0.5 * self.delta_m[0], 0.5 * self.delta_m[1]), 0.5 * math.hypot(*self.delta_m)

    def _phase(self, t: np.ndarray) -> np.ndarray:
        length = math.hypot(*self.delta_m)
        if length == 0 or self.speed_m_s == 0:
            return np.zeros_like(t)
        s = np.mod(t * self.speed_m_s, 2.0 * length)
        return np.where(s <= length, s, 2.0 * length - s) / length

    def offset_at(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        frac = self._phase(t)
        return np.stack([frac * self.delta_m[0], frac * self.delta_m[1]], axis=-1)

    def velocity_at(self, t_s: float) -> tuple[float, float]:
        length = math.hypot(*self.delta_m)
        if length == 0 or self.speed_m_s == 0:
            return 0.0, 0.0
        s = (t_s * self.speed_m_s) % (2.0 * length)
        sign = 1.0 if s < length else -1.0
        k = sign * self.speed_m_s / length
        return k * self.delta_m[0], k * self.delta_m[1]


@dataclass(frozen=True, slots=True)
class Orbit:
    """Circular orbit of the shape's reference point around ``pivot`` at constant speed."""

    pivot_m: tuple[float, float]
    start_m: tuple[float, float]
    speed_m_s: float
    clockwise: bool = False

    @property
    def is_moving(self) -> bool:
        return self.speed_m_s > 0 and self._radius > 0

    @property
    def _radius(self) -> float:
        return math.hypot(self.start_m[0] - self.pivot_m[0], self.start_m[1] - self.pivot_m[1])

    @property
    def offset_disc(self) -> tuple[tuple[float, float], float]:
        """A disc (centre, radius) holding every offset the motion ever takes: the orbit's."""
        return (self.pivot_m[0] - self.start_m[0], self.pivot_m[1] - self.start_m[1]), self._radius

    def _angle(self, t: np.ndarray) -> np.ndarray:
        r = self._radius
        phi0 = math.atan2(self.start_m[1] - self.pivot_m[1], self.start_m[0] - self.pivot_m[0])
        omega = 0.0 if r == 0 else self.speed_m_s / r
        return phi0 + (-omega if self.clockwise else omega) * t

    def offset_at(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        r = self._radius
        phi = self._angle(t)
        x = self.pivot_m[0] + r * np.cos(phi) - self.start_m[0]
        y = self.pivot_m[1] + r * np.sin(phi) - self.start_m[1]
        return np.stack([x, y], axis=-1)

    def velocity_at(self, t_s: float) -> tuple[float, float]:
        if not self.is_moving:
            return 0.0, 0.0
        phi = float(self._angle(np.asarray(t_s)))
        sign = -1.0 if self.clockwise else 1.0
        return -sign * self.speed_m_s * math.sin(phi), sign * self.speed_m_s * math.cos(phi)


@dataclass(frozen=True, slots=True)
class Patrol:
    """A closed loop through waypoints (the shape's start position first) at constant speed."""

    loop_m: tuple[tuple[float, float], ...]  # first point is the start position
    speed_m_s: float

    @property
    def is_moving(self) -> bool:
        return self.speed_m_s > 0 and self._length > 0

    @property
    def offset_disc(self) -> tuple[tuple[float, float], float]:
        """A disc (centre, radius) holding every offset the motion ever takes: one round the
        loop's points (the loop runs between them)."""
        pts = np.asarray(self.loop_m, dtype=float)
        mid = pts.mean(axis=0)
        return ((float(mid[0] - pts[0, 0]), float(mid[1] - pts[0, 1])),
                float(np.hypot(*(pts - mid).T).max()))

    @property
    def _length(self) -> float:
        pts = np.asarray(self.loop_m + (self.loop_m[0],), dtype=float)
        return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))

    def _position(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = np.asarray(self.loop_m + (self.loop_m[0],), dtype=float)
        seg = np.diff(pts, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        cum = np.concatenate([[0.0], np.cumsum(seg_len)])
        total = cum[-1]
        s = np.mod(t * self.speed_m_s, total) if total > 0 else np.zeros_like(t)
        idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        frac = np.where(seg_len[idx] > 0, (s - cum[idx]) / np.where(seg_len[idx] > 0, seg_len[idx], 1.0), 0.0)
        pos = pts[idx] + seg[idx] * frac[..., None]
        return pos, idx

    def offset_at(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        if not self.is_moving:
            return np.zeros(t.shape + (2,))
        pos, _ = self._position(t)
        return pos - np.asarray(self.loop_m[0], dtype=float)

    def velocity_at(self, t_s: float) -> tuple[float, float]:
        if not self.is_moving:
            return 0.0, 0.0
        pts = np.asarray(self.loop_m + (self.loop_m[0],), dtype=float)
        _, idx = self._position(np.asarray(t_s, dtype=float))
        d = pts[int(idx) + 1] - pts[int(idx)]
        n = math.hypot(d[0], d[1])
        return float(d[0] / n * self.speed_m_s), float(d[1] / n * self.speed_m_s)


Motion = Static | Shuttle | Orbit | Patrol


@dataclass(frozen=True)
class Obstacle:
    """One obstacle: its true footprint at t = 0, its inflated footprint, and its motion.

    ``size_m`` is the circumradius about ``center``; the inflation margin is a fraction of it
    (paper: +20 %), so a circle of radius R inflates to exactly R * (1 + ratio).
    """

    id: str
    kind: ShapeKind
    center: tuple[float, float]
    size_m: float
    footprint: Polygon  # true shape at t = 0 (a circle is a fine polygon here; see is_circle)
    margin_m: float
    motion: Motion = field(default_factory=Static)

    @property
    def is_circle(self) -> bool:
        return self.kind == "circle"

    @property
    def is_moving(self) -> bool:
        return self.motion.is_moving

    @property
    def inflated_radius_m(self) -> float:
        """Radius of the inflated disk (circles); the inflated circumradius otherwise."""
        return self.size_m + self.margin_m

    @property
    def inflated(self) -> Polygon:
        """Inflated footprint at t = 0: the true shape buffered by the margin (round joins)."""
        if self.is_circle:
            return Point(self.center).buffer(self.inflated_radius_m, quad_segs=CIRCLE_QUAD_SEGS)
        return self.footprint.buffer(self.margin_m, quad_segs=CIRCLE_QUAD_SEGS)

    def offset_at(self, t_s: np.ndarray | float) -> np.ndarray:
        return self.motion.offset_at(t_s)

    def center_at(self, t_s: float) -> tuple[float, float]:
        dx, dy = self.motion.offset_at(t_s)
        return self.center[0] + float(dx), self.center[1] + float(dy)

    def footprint_at(self, t_s: float) -> Polygon:
        dx, dy = self.motion.offset_at(t_s)
        return affinity.translate(self.footprint, float(dx), float(dy))

    def inflated_at(self, t_s: float) -> Polygon:
        dx, dy = self.motion.offset_at(t_s)
        return affinity.translate(self.inflated, float(dx), float(dy))

    def vertices(self) -> np.ndarray:
        """Vertices (N, 2) of the true footprint at t = 0, without the closing repeat."""
        return np.asarray(self.footprint.exterior.coords, dtype=float)[:-1]


def make_obstacle(id: str, kind: ShapeKind, *, center: tuple[float, float] | None = None,
                  radius_m: float | None = None, width_m: float | None = None,
                  height_m: float | None = None, circumradius_m: float | None = None,
                  vertices: list[tuple[float, float]] | None = None, rotation_deg: float = 0.0,
                  inflation_ratio: float = 0.2, motion: Motion | None = None) -> Obstacle:
    """Build an obstacle from its shape parameters (ENU metres, rotation CCW in degrees)."""
    if kind == "circle":
        assert center is not None and radius_m is not None
        footprint = Point(center).buffer(radius_m, quad_segs=CIRCLE_QUAD_SEGS)
        size = radius_m
    elif kind == "rectangle":
        assert center is not None and width_m is not None and height_m is not None
        cx, cy = center
        hw, hh = width_m / 2.0, height_m / 2.0
        footprint = Polygon([(cx - hw, cy - hh), (cx + hw, cy - hh), (cx + hw, cy + hh), (cx - hw, cy + hh)])
        footprint = affinity.rotate(footprint, rotation_deg, origin=center)
        size = math.hypot(hw, hh)
    elif kind == "triangle":
        assert center is not None and circumradius_m is not None
        cx, cy = center
        base = math.radians(90.0 + rotation_deg)
        footprint = Polygon([(cx + circumradius_m * math.cos(base + k * 2.0 * math.pi / 3.0),
                              cy + circumradius_m * math.sin(base + k * 2.0 * math.pi / 3.0))
                             for k in range(3)])
        size = circumradius_m
    elif kind == "polygon":
        assert vertices is not None and len(vertices) >= 3
        footprint = Polygon(vertices)
        if rotation_deg:
            footprint = affinity.rotate(footprint, rotation_deg, origin="centroid")
        c = footprint.centroid
        center = (c.x, c.y)
        size = max(math.hypot(x - c.x, y - c.y) for x, y in footprint.exterior.coords)
    else:  # pragma: no cover - the mission schema admits only the kinds above
        raise ValueError(f"unknown obstacle shape {kind!r}")
    footprint = shapely.normalize(footprint)
    return Obstacle(id=id, kind=kind, center=(float(center[0]), float(center[1])), size_m=float(size),
                    footprint=footprint, margin_m=float(inflation_ratio * size),
                    motion=motion if motion is not None else Static())


@dataclass(frozen=True)
class World:
    """Area, geofence and obstacles, in ENU metres."""

    x_min_m: float
    y_min_m: float
    x_max_m: float
    y_max_m: float
    geofence_margin_m: float
    obstacles: tuple[Obstacle, ...]

    @property
    def static_obstacles(self) -> tuple[Obstacle, ...]:
        return tuple(o for o in self.obstacles if not o.is_moving)

    @property
    def moving_obstacles(self) -> tuple[Obstacle, ...]:
        return tuple(o for o in self.obstacles if o.is_moving)

    @property
    def geofence(self) -> Polygon:
        m = self.geofence_margin_m
        return shapely.box(self.x_min_m - m, self.y_min_m - m, self.x_max_m + m, self.y_max_m + m)

    def inside_geofence(self, x_m: float, y_m: float) -> bool:
        m = self.geofence_margin_m
        return (self.x_min_m - m <= x_m <= self.x_max_m + m) and (self.y_min_m - m <= y_m <= self.y_max_m + m)
