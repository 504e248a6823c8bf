"""Global routes for every vehicle: A* on the grid, the paper's priority rule, sparse optimisation.

Priority (paper section III.A, last paragraph): vehicles are planned in ``mission.by_priority``
order. The first is planned freely. Each later vehicle must keep to the other side of the line
joining the start and goal of every earlier route. Blocked for it (as extra grid obstacles):
  * each earlier (sparse) route, buffered by the minimum separation;
  * that route's side: the half-plane of its start-goal line that it lies in (clipped to the
    declared area, the keep-in), or, when the route crosses its own line, every lobe it encloses with the
    line (there is no single side then, so the later vehicle goes around all of them).
Discs of radius ``min_separation + 2 cells`` around the later vehicle's own start and goal are
exempt: stations are shared, and meeting there is separated in time, which is the local
planner's job. The line is geometric, so the direction each vehicle flies does not matter.

With more than two vehicles no route is constrained (see plan_routes), except by assignment: a
mission that names its sight-line pairs (``sightline.pairs``) keeps the lower vehicle of each
pair to the other side of its partner's route, as the paper's pair does.

If that makes the later route impossible, the constraint is relaxed, and the Route records what
held:

    "opposite-side"   earlier routes and their sides blocked (the paper's rule)
    "avoid-route"     only the earlier routes, buffered by the separation, blocked
    "none"            the first vehicle, or no constrained route exists

The sparse route of a constrained vehicle is shortcut only where the same constraint allows, so
sparse optimisation never pulls it back across.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from uav_model.mission import Mission
from companion.planning.astar import astar, path_length_m
from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import OccupancyGrid, rasterise
from companion.planning.sparse import sparsify
from uav_model.fence_margin import keep_in_box
from uav_model.world import World

Constraint = Literal["opposite-side", "avoid-route", "none"]

_MIN_SIDE_AREA_M2 = 1.0  # a route along its own chord encloses nothing: no side to keep off


@dataclass(frozen=True, eq=False)
class Route:
    """One vehicle's global route in ENU metres: every A* cell, and the sparse key nodes."""

    vehicle: str
    raw_enu_m: np.ndarray     # (N, 2): exact start, cell centres, exact goal
    sparse_enu_m: np.ndarray  # (M, 2): a subsequence of raw with the same ends
    constraint: Constraint = "none"

    @property
    def nodes_raw(self) -> int:
        return len(self.raw_enu_m)

    @property
    def nodes_sparse(self) -> int:
        return len(self.sparse_enu_m)

    @property
    def length_m(self) -> float:
        """Length of the sparse route (what the vehicle is asked to fly)."""
        return path_length_m(self.sparse_enu_m)

    @property
    def raw_length_m(self) -> float:
        return path_length_m(self.raw_enu_m)


def plan_routes(mission: Mission, *, max_expansions: int | None = None) -> dict[str, Route]:
    """Routes for all vehicles, keyed by name, planned in priority order (see the module doc).

    Raises :class:`NoPath` naming the vehicle when even the unconstrained grid has no route
    (start or goal blocked, goal walled in), and :class:`BudgetExceeded` when a search hits
    ``max_expansions`` (a budget is a cap on work, so it is not answered by relaxing constraints).
    """
    world = mission.world
    resolution_m = mission.planner.grid_resolution_m
    ends = [xy for v in mission.vehicles for xy in (v.start_enu_m, v.goal_enu_m)]
    base = rasterise(world, resolution_m, keep_in_with=ends)
    routes: dict[str, Route] = {}
    for vehicle in mission.by_priority:
        earlier = higher_routes(mission, routes, vehicle.name)
        failure: NoPath | None = None
        ladder = _constraint_ladder(earlier, (vehicle.start_enu_m, vehicle.goal_enu_m),
                                    mission.safety.min_separation_m, resolution_m, shapely.box(*keep_in_box(world)))
        for constraint, blocked in ladder:
            grid = base.with_geometry_blocked(blocked) if blocked else base
            try:
                raw = astar(grid, vehicle.start_enu_m, vehicle.goal_enu_m, max_expansions=max_expansions)
            except BudgetExceeded as exc:
                raise exc.for_vehicle(vehicle.name) from None
            except NoPath as exc:
                failure = exc
                continue
            sparse = sparsify(raw, world, extra=blocked)
            routes[vehicle.name] = Route(vehicle.name, raw, sparse, constraint)
            break
        else:
            assert failure is not None
            raise failure.for_vehicle(vehicle.name) from None
    return routes


def detour_route(grid: OccupancyGrid, world: World, from_xy: tuple[float, float],
                 goal_xy: tuple[float, float], *, sparse: bool = True,
                 max_expansions: int | None = None, earlier: Sequence[Route] = (),
                 separation_m: float = 0.0) -> np.ndarray:
    """A new route (M, 2) from where a vehicle is now to its goal, sparse or every A* cell, on
    the static ``grid`` (the world rasterised as for :func:`plan_routes`), for a vehicle that
    stopped making progress.

    The priority rule still holds: with the ``earlier`` (higher-priority) routes given, the
    constrained steps are tried first, as :func:`plan_routes` does (opposite side, then off their
    routes), with discs around the vehicle's position and its goal exempt; only when none gives
    a route is the plain grid used.

    A vehicle skirting an obstacle may sit in a cell the conservative rasterisation marks
    occupied; the search then starts from the nearest free cell (within 10 cells), and the
    route's first point is still the vehicle's own position. Raises :class:`NoPath` when there
    is no free cell near or no route, :class:`BudgetExceeded` past ``max_expansions``.
    """
    x, y = float(from_xy[0]), float(from_xy[1])
    start = _nearest_free_centre(grid, x, y, 10)
    ladder = _constraint_ladder(list(earlier), (start, tuple(goal_xy)), separation_m, grid.resolution_m,
                                 shapely.box(*keep_in_box(world)))
    for constraint, blocked in ladder:
        try:
            raw = astar(grid.with_geometry_blocked(blocked) if blocked else grid, start, goal_xy,
                        max_expansions=max_expansions)
        except BudgetExceeded:
            raise
        except NoPath:
            if constraint == "none":
                raise
            continue
        if (start[0], start[1]) != (x, y):
            raw = np.vstack([[x, y], raw])
        return sparsify(raw, world, extra=blocked) if sparse else raw
    raise AssertionError("the constraint ladder always ends with 'none'")


def priority_rule_applies(mission: Mission) -> bool:
    """The paper's rule is for a pair. With more vehicles whose routes must cross (a fleet flying
    across the square), it pushes each later route around the ends of the earlier ones, along
    the area's edge; their routes are planned freely and the local planner keeps the
    separation (:mod:`companion.planning.fleet`)."""
    return len(mission.vehicles) <= 2


def higher_routes(mission: Mission, routes: Mapping[str, Route], name: str) -> list[Route]:
    """The routes that constrain ``name``'s: those of the vehicles planned before it (higher
    priority), in that order, when the priority rule applies; otherwise those of the partners it
    is assigned to hide from (``Mission.hides_from``; none without an assignment)."""
    if not priority_rule_applies(mission):
        return [routes[n] for n in mission.hides_from(name) or () if n in routes]
    order = [v.name for v in mission.by_priority]
    return [routes[n] for n in order[:order.index(name)] if n in routes]


def _nearest_free_centre(grid: OccupancyGrid, x: float, y: float, cells: int) -> tuple[float, float]:
    """(x, y) itself when its cell is free, else the centre of the nearest free cell within
    ``cells`` cells of it."""
    ix, iy = grid.world_to_cell(x, y)
    if grid.is_free(ix, iy):
        return x, y
    ny, nx = grid.shape
    x0, x1 = max(ix - cells, 0), min(ix + cells + 1, nx)
    y0, y1 = max(iy - cells, 0), min(iy + cells + 1, ny)
    if x0 >= x1 or y0 >= y1:
        raise NoPath(f"({x:.1f}, {y:.1f}) is outside the grid")
    free_y, free_x = np.nonzero(~grid.occupied[y0:y1, x0:x1])
    if not free_x.size:
        raise NoPath(f"no free grid cell within {cells} cells of ({x:.1f}, {y:.1f})")
    k = int(np.argmin((free_x + x0 - ix) ** 2 + (free_y + y0 - iy) ** 2))
    return grid.cell_to_world(int(free_x[k]) + x0, int(free_y[k]) + y0)


def _constraint_ladder(earlier: Sequence[Route], ends: tuple[Sequence[float], Sequence[float]], separation_m: float,
                       resolution_m: float, box: BaseGeometry) -> list[tuple[Constraint, list[BaseGeometry]]]:
    """The constraints to try for a vehicle going between ``ends``, strictest first, each with
    the geometry it blocks."""
    if not earlier:
        return [("none", [])]
    exempt_m = separation_m + 2.0 * resolution_m
    exempt = shapely.union(Point(ends[0]).buffer(exempt_m), Point(ends[1]).buffer(exempt_m))
    bands = shapely.union_all([LineString(r.sparse_enu_m).buffer(separation_m) for r in earlier])
    sides = shapely.union_all([side_region(r.sparse_enu_m, box) for r in earlier])
    ladder: list[tuple[Constraint, list[BaseGeometry]]] = []
    if sides.area >= _MIN_SIDE_AREA_M2:
        ladder.append(("opposite-side", [shapely.union(bands, sides).difference(exempt)]))
    ladder.append(("avoid-route", [bands.difference(exempt)]))
    ladder.append(("none", []))
    return ladder


def side_region(route_enu_m: np.ndarray, box: BaseGeometry) -> BaseGeometry:
    """The side of its start-goal line that a route keeps to, clipped to ``box``.

    A route on one side (touching the line is allowed) gives that whole half-plane; a route that
    crosses the line gives the lobes it encloses with the segment; a straight route gives nothing.
    """
    p = np.asarray(route_enu_m, dtype=float)
    a, b = p[0], p[-1]
    chord = b - a
    length = float(np.hypot(*chord))
    if len(p) < 3 or length == 0.0:
        return shapely.Polygon()
    rel = p[1:-1] - a
    cross = (chord[0] * rel[:, 1] - chord[1] * rel[:, 0]) / length  # signed distance, + is left
    tol = 1e-9 * max(length, 1.0)
    left, right = bool(np.any(cross > tol)), bool(np.any(cross < -tol))
    if left and right:
        linework = shapely.union(LineString(p), LineString([b, a]))  # the union nodes the crossings
        return shapely.union_all(list(shapely.polygonize([linework]).geoms))
    if not (left or right):
        return shapely.Polygon()
    x0, y0, x1, y1 = box.bounds
    reach = 2.0 * (float(np.hypot(x1 - x0, y1 - y0)) + float(np.hypot(*(a - (x0, y0)))))
    d = chord / length
    n = np.array([-d[1], d[0]]) * (1.0 if left else -1.0) * reach
    far_a, far_b = a - d * reach, b + d * reach
    return shapely.Polygon([far_a, far_b, far_b + n, far_a + n]).intersection(box)
