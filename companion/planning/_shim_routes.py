"""TEMPORARY SHIM (local-planning engineer): stands in for routes.py / bounds.py until they land.
Self-contained tiny grid A*; delete once companion.planning.routes and .bounds exist."""
from __future__ import annotations
import heapq, math
from dataclasses import dataclass
import numpy as np
import shapely
from shapely.geometry import LineString, Point
from companion.planning.errors import NoPath


@dataclass(frozen=True)
class Route:
    vehicle: str
    raw_enu_m: np.ndarray
    sparse_enu_m: np.ndarray

    @property
    def nodes_raw(self): return len(self.raw_enu_m)

    @property
    def nodes_sparse(self): return len(self.sparse_enu_m)


def _grid(world, res, extra=None):
    fx0, fy0, fx1, fy1 = world.geofence.bounds
    xs = np.arange(fx0 + res / 2, fx1, res); ys = np.arange(fy0 + res / 2, fy1, res)
    gx, gy = np.meshgrid(xs, ys)
    occ = np.zeros(gx.shape, bool)
    h = res * math.sqrt(2) / 2
    for o in world.static_obstacles:
        occ |= shapely.intersects_xy(o.inflated.buffer(h), gx, gy)
    if extra is not None:
        occ |= shapely.intersects_xy(extra.buffer(h), gx, gy)
    return xs, ys, occ


def _astar(xs, ys, occ, start, goal, res):
    ny, nx = occ.shape
    cell = lambda p: (min(nx - 1, max(0, int((p[0] - xs[0] + res / 2) // res))), min(ny - 1, max(0, int((p[1] - ys[0] + res / 2) // res))))
    s, g = cell(start), cell(goal)
    occ = occ.copy(); occ[s[1], s[0]] = False; occ[g[1], g[0]] = False
    h = lambda c: max(abs(c[0] - g[0]), abs(c[1] - g[1])) + (math.sqrt(2) - 1) * min(abs(c[0] - g[0]), abs(c[1] - g[1]))
    best = {s: 0.0}; parent = {s: None}; pq = [(h(s), 0.0, s)]
    while pq:
        f, gc, c = heapq.heappop(pq)
        if c == g: break
        if gc > best[c]: continue
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                if dx == dy == 0: continue
                n = (c[0] + dx, c[1] + dy)
                if not (0 <= n[0] < nx and 0 <= n[1] < ny) or occ[n[1], n[0]]: continue
                if dx and dy and (occ[c[1], n[0]] or occ[n[1], c[0]]): continue
                ng = gc + (math.sqrt(2) if dx and dy else 1.0)
                if ng < best.get(n, math.inf):
                    best[n] = ng; parent[n] = c; heapq.heappush(pq, (ng + h(n), ng, n))
    else:
        raise NoPath("shim: walled in")
    path = []
    c = g
    while c is not None:
        path.append((xs[c[0]], ys[c[1]])); c = parent[c]
    path = path[::-1]
    path[0] = tuple(start); path[-1] = tuple(goal)
    return np.array(path)


def _sparse(path, world):
    infl = shapely.union_all([o.inflated for o in world.static_obstacles]) if world.static_obstacles else None
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1:
            if infl is None or not LineString([path[i], path[j]]).intersects(infl):
                break
            j -= 1
        out.append(path[j]); i = j
    return np.array(out)


def plan_routes(mission):
    res = mission.planner.grid_resolution_m
    routes = {}
    first = None
    for v in mission.by_priority:
        extra = None if first is None else LineString(first[5:-5])
        xs, ys, occ = _grid(mission.world, res, extra)
        raw = _astar(xs, ys, occ, v.start_enu_m, v.goal_enu_m, res)
        if first is None:
            first = raw
        routes[v.name] = Route(v.name, raw, _sparse(raw, mission.world))
    return routes


def lower_bound_m(world, start, goal):
    circles = [o for o in world.static_obstacles if o.is_circle]
    a = np.asarray(start); b = np.asarray(goal)
    if len(circles) != 1:
        return float(np.hypot(*(b - a)))
    o = circles[0]; R = o.inflated_radius_m; c = np.asarray(o.center)
    if LineString([start, goal]).distance(Point(c)) >= R:
        return float(np.hypot(*(b - a)))
    da = np.hypot(*(a - c)); db = np.hypot(*(b - c))
    th = math.acos(np.dot(a - c, b - c) / da / db)
    return math.sqrt(da**2 - R**2) + math.sqrt(db**2 - R**2) + R * (th - math.acos(R / da) - math.acos(R / db))


def lower_bound_s(world, start, goal, speed):
    return lower_bound_m(world, start, goal) / speed
