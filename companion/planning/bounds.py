"""Physical lower bounds on path length and flight time (SPEC §1), for reporting every flight.

The bound is the shortest path from start to goal that stays out of the inflated STATIC
obstacles (moving ones can only make a flight longer, and a turn radius only adds to it):
  * nothing in the way: the straight line;
  * exactly one static obstacle, a disc: the closed form tangent + arc + tangent,
    L = sqrt(a^2-R^2) + sqrt(b^2-R^2) + R*(theta - acos(R/a) - acos(R/b)), 4737.7 m in the
    reference scenario;
  * otherwise: Dijkstra over the visibility graph of the obstacles' inflated outlines. Circles
    and round corners become INSCRIBED polygons (vertices on the true curve, 16 per quarter
    turn), so any path that avoids the true shapes also avoids the polygons: the result never
    exceeds the true shortest path and falls short of it by under 0.05 % (on the arcs only).
    Only bitangent edges are tested for visibility (a shortest path bends only where it wraps
    around a vertex), numpy picks them, shapely tests them all at once.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from companion.planning.errors import NoPath, PlanningError
from uav_model.world import Obstacle, World

OUTLINE_QUAD_SEGS = 16  # inscribed vertices per quarter turn of a circle or a round corner
_TANGENT_CHUNK = 256     # rows of the vertex-pair matrix built at once (bounds memory)


def lower_bound_m(world: World, start_xy: Sequence[float], goal_xy: Sequence[float]) -> float:
    """Shortest distance from start to goal around the inflated static obstacles, in metres."""
    start, goal = _point(start_xy, "start"), _point(goal_xy, "goal")
    statics = world.static_obstacles
    if len(statics) == 1 and statics[0].is_circle:
        o = statics[0]
        return disk_detour_m(start, goal, o.center, o.inflated_radius_m)
    if not statics:
        return math.dist(start, goal)
    union = shapely.union_all([inscribed_outline(o) for o in statics])
    for name, p in (("start", start), ("goal", goal)):
        if union.contains(Point(p)):
            raise PlanningError(f"{name} ({p[0]:.1f}, {p[1]:.1f}) is inside an inflated obstacle: no lower bound")
    # Edges may run along an outline or touch it at a vertex, but not cut through: test against
    # the outlines shrunk by a hair (nanometres per kilometre), which keeps the bound a bound.
    x0, y0, x1, y1 = union.bounds
    solid = union.buffer(-1e-9 * max(x1 - x0, y1 - y0, 1.0))
    shapely.prepare(solid)
    if not solid.intersects(LineString([start, goal])):
        return math.dist(start, goal)
    return _visibility_shortest_m(start, goal, union, solid)


def lower_bound_s(world: World, start_xy: Sequence[float], goal_xy: Sequence[float], speed_m_s: float) -> float:
    """The lower bound on flight time at constant ``speed_m_s``."""
    if not (math.isfinite(speed_m_s) and speed_m_s > 0):
        raise PlanningError(f"speed must be a positive number of m/s, got {speed_m_s!r}")
    return lower_bound_m(world, start_xy, goal_xy) / speed_m_s


def disk_detour_m(start_xy: Sequence[float], goal_xy: Sequence[float], center_xy: Sequence[float],
                  radius_m: float) -> float:
    """Shortest path from start to goal outside one disc: straight, or tangent + arc + tangent."""
    s, g, c = (np.asarray(v, dtype=float) for v in (start_xy, goal_xy, center_xy))
    if LineString([s, g]).distance(Point(c)) >= radius_m or np.array_equal(s, g):
        return float(np.hypot(*(g - s)))
    a, b = float(np.hypot(*(s - c))), float(np.hypot(*(g - c)))
    if a < radius_m or b < radius_m:
        raise PlanningError(f"an end point lies inside the disc of radius {radius_m:g} m: no detour around it")
    theta = math.acos(max(-1.0, min(1.0, float(np.dot(s - c, g - c)) / (a * b))))
    return (math.sqrt(a * a - radius_m * radius_m) + math.sqrt(b * b - radius_m * radius_m)
            + radius_m * (theta - math.acos(radius_m / a) - math.acos(radius_m / b)))


def inscribed_outline(o: Obstacle) -> Polygon:
    """The obstacle's inflated shape with every curve replaced by an inscribed polygon."""
    if o.is_circle:
        return Point(o.center).buffer(o.inflated_radius_m, quad_segs=OUTLINE_QUAD_SEGS)
    return o.footprint.buffer(o.margin_m, quad_segs=OUTLINE_QUAD_SEGS)


def _point(xy: Sequence[float], name: str) -> tuple[float, float]:
    x, y = float(xy[0]), float(xy[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise PlanningError(f"{name} ({x}, {y}) is not a finite point")
    return x, y


def _rings(geom: BaseGeometry) -> list[np.ndarray]:
    """Vertex arrays (open) of every exterior and interior ring of a (multi)polygon."""
    polygons = geom.geoms if hasattr(geom, "geoms") else [geom]
    rings = []
    for poly in polygons:
        for ring in (poly.exterior, *poly.interiors):
            rings.append(np.asarray(ring.coords, dtype=float)[:-1])
    return rings


def _visibility_shortest_m(start: tuple[float, float], goal: tuple[float, float],
                           outlines: BaseGeometry, solid: BaseGeometry) -> float:
    rings = _rings(outlines)
    verts = np.vstack([np.array([start, goal])] + rings)
    # Ring neighbours of every vertex; start and goal are their own (every line is tangent there).
    prev = np.vstack([np.array([start, goal])] + [np.roll(r, 1, axis=0) for r in rings])
    nxt = np.vstack([np.array([start, goal])] + [np.roll(r, -1, axis=0) for r in rings])
    tangent = np.zeros((len(verts), len(verts)), dtype=bool)
    for lo in range(0, len(verts), _TANGENT_CHUNK):
        rows = slice(lo, lo + _TANGENT_CHUNK)
        d = verts[None, :, :] - verts[rows, None, :]               # from row vertex to every vertex
        tangent[rows] = _keeps_neighbours_on_one_side(d, prev[rows] - verts[rows], nxt[rows] - verts[rows])
    i, j = np.nonzero(np.triu(tangent & tangent.T, k=1))
    segments = shapely.linestrings(np.stack([verts[i], verts[j]], axis=1))
    visible = ~shapely.intersects(solid, segments)
    i, j = i[visible], j[visible]
    weights = np.hypot(*(verts[j] - verts[i]).T)
    adjacency: list[list[tuple[int, float]]] = [[] for _ in range(len(verts))]
    for u, v, w in zip(i.tolist(), j.tolist(), weights.tolist()):
        adjacency[u].append((v, w))
        adjacency[v].append((u, w))
    dist = [math.inf] * len(verts)
    dist[0] = 0.0
    heap = [(0.0, 0)]
    while heap:
        du, u = heapq.heappop(heap)
        if u == 1:
            return du
        if du > dist[u]:
            continue
        for v, w in adjacency[u]:
            if du + w < dist[v]:
                dist[v] = du + w
                heapq.heappush(heap, (du + w, v))
    raise NoPath(f"goal ({goal[0]:.1f}, {goal[1]:.1f}) unreachable from start ({start[0]:.1f}, {start[1]:.1f}) "
                 "around the inflated static obstacles: walled in")


def _keeps_neighbours_on_one_side(d: np.ndarray, to_prev: np.ndarray, to_next: np.ndarray) -> np.ndarray:
    """(R, M): does the line from row vertex r along d[r, m] leave both its ring neighbours on one side?"""
    def sine(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        cross = u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0]
        norm = np.hypot(u[..., 0], u[..., 1]) * np.hypot(w[..., 0], w[..., 1])
        return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)

    s1 = sine(d, to_prev[:, None, :])
    s2 = sine(d, to_next[:, None, :])
    eps = 1e-9
    return ~(((s1 < -eps) & (s2 > eps)) | ((s1 > eps) & (s2 < -eps)))
