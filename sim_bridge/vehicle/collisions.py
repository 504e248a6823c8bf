"""Ground truth: does a flown step touch a true (un-inflated) obstacle footprint? Pure.

The check runs on each physics step's segment, not on samples. For a moving obstacle it works
in the obstacle's own frame: over one short step the obstacle translates (nearly) linearly, so
the vehicle's path relative to it is the segment from ``p0 - offset(t0)`` to ``p1 - offset(t1)``,
tested against the footprint at t = 0. That is exact for shuttle and patrol legs and closer
than sampling for orbits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import shapely
from shapely.geometry import LineString, Point

from uav_model.world import Obstacle, Orbit, Patrol, Shuttle, World


@dataclass(frozen=True, slots=True)
class CollisionEvent:
    """A vehicle entered an obstacle's true footprint."""

    t_s: float
    obstacle_id: str
    x_m: float
    y_m: float


def _motion_envelope(o: Obstacle, radius: float) -> tuple[float, float, float]:
    """A circle (cx, cy, r) that holds the obstacle at every time: a cheap test to skip it."""
    cx, cy = o.center
    m = o.motion
    if isinstance(m, Shuttle):
        dx, dy = m.delta_m
        return cx + dx / 2.0, cy + dy / 2.0, math.hypot(dx, dy) / 2.0 + radius
    if isinstance(m, Orbit):
        px, py = m.pivot_m
        return px, py, math.hypot(cx - px, cy - py) + radius
    if isinstance(m, Patrol):
        xs = [p[0] for p in m.loop_m]
        ys = [p[1] for p in m.loop_m]
        mx, my = (min(xs) + max(xs)) / 2.0, (min(ys) + max(ys)) / 2.0
        reach = max(math.hypot(x - mx, y - my) for x, y in m.loop_m)
        return mx + cx - m.loop_m[0][0], my + cy - m.loop_m[0][1], reach + radius
    return cx, cy, math.inf  # unknown motion: never skip


def _segment_point_distance(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    dx, dy = bx - ax, by - ay
    n2 = dx * dx + dy * dy
    if n2 <= 0.0:
        return math.hypot(px - ax, py - ay)
    u = max(0.0, min(1.0, ((px - ax) * dx + (py - ay) * dy) / n2))
    return math.hypot(ax + u * dx - px, ay + u * dy - py)


class CollisionChecker:
    """Segment-vs-true-footprint tests for every obstacle of a world."""

    def __init__(self, world: World):
        self._obstacles: tuple[Obstacle, ...] = world.obstacles
        self._footprints = []
        for o in self._obstacles:
            fp = shapely.Polygon(o.footprint)  # a private copy, so preparing it touches no shared object
            shapely.prepare(fp)
            self._footprints.append(fp)
        # Bounding radius about the reference centre: the footprint lies inside it.
        self._radius = [max(math.hypot(x - o.center[0], y - o.center[1]) for x, y in o.footprint.exterior.coords)
                        for o in self._obstacles]
        self._envelope = [_motion_envelope(o, r) if o.is_moving else None
                          for o, r in zip(self._obstacles, self._radius)]
        # Offsets at the end of the last step, reused as the start of the next (one numpy call a step).
        self._offset_cache: dict[int, tuple[float, tuple[float, float]]] = {}

    def _offset(self, k: int, t_s: float) -> tuple[float, float]:
        cached = self._offset_cache.get(k)
        if cached is not None and cached[0] == t_s:
            return cached[1]
        d = self._obstacles[k].offset_at(t_s)
        out = (float(d[0]), float(d[1]))
        self._offset_cache[k] = (t_s, out)
        return out

    def hits(self, x0_m: float, y0_m: float, x1_m: float, y1_m: float, t0_s: float, t1_s: float) -> list[str]:
        """Ids of obstacles whose true footprint the ENU segment (x0,y0)@t0 -> (x1,y1)@t1 touches."""
        out: list[str] = []
        for k, (o, fp, radius) in enumerate(zip(self._obstacles, self._footprints, self._radius)):
            env = self._envelope[k]
            if env is not None:
                if _segment_point_distance(x0_m, y0_m, x1_m, y1_m, env[0], env[1]) > env[2] + 1e-6:
                    continue  # nowhere near anywhere the obstacle can be
                d0 = self._offset(k, t0_s)
                d1 = self._offset(k, t1_s)
                ax, ay = x0_m - d0[0], y0_m - d0[1]
                bx, by = x1_m - d1[0], y1_m - d1[1]
            else:
                ax, ay, bx, by = x0_m, y0_m, x1_m, y1_m
            if _segment_point_distance(ax, ay, bx, by, o.center[0], o.center[1]) > radius + 1e-6:
                continue
            geom = Point(ax, ay) if (ax, ay) == (bx, by) else LineString([(ax, ay), (bx, by)])
            if fp.intersects(geom):
                out.append(o.id)
        return out
