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

from companion.planning.world import Obstacle, World


@dataclass(frozen=True, slots=True)
class CollisionEvent:
    """A vehicle entered an obstacle's true footprint."""

    t_s: float
    obstacle_id: str
    x_m: float
    y_m: float


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

    def hits(self, x0_m: float, y0_m: float, x1_m: float, y1_m: float, t0_s: float, t1_s: float) -> list[str]:
        """Ids of obstacles whose true footprint the ENU segment (x0,y0)@t0 -> (x1,y1)@t1 touches."""
        out: list[str] = []
        for o, fp, radius in zip(self._obstacles, self._footprints, self._radius):
            if o.is_moving:
                d0 = o.offset_at(t0_s)
                d1 = o.offset_at(t1_s)
                ax, ay = x0_m - float(d0[0]), y0_m - float(d0[1])
                bx, by = x1_m - float(d1[0]), y1_m - float(d1[1])
            else:
                ax, ay, bx, by = x0_m, y0_m, x1_m, y1_m
            if _segment_point_distance(ax, ay, bx, by, o.center[0], o.center[1]) > radius + 1e-6:
                continue
            geom = Point(ax, ay) if (ax, ay) == (bx, by) else LineString([(ax, ay), (bx, by)])
            if fp.intersects(geom):
                out.append(o.id)
        return out
