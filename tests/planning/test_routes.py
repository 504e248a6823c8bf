"""Global routes: the paper's priority rule (opposite sides of A-B), its fallbacks, typed failures."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from shapely.geometry import LineString, Point, box

from uav_model.mission import Mission, load_mission
from companion.planning.astar import astar, path_length_m
from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import rasterise
from companion.planning.routes import Route, plan_routes, side_region
from uav_model.world import World, make_obstacle
from world_strategies import SIDE_M, worlds

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"
RANDOM = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def mission_with(world: World, a_xy, b_xy, resolution_m: float = 20.0) -> Mission:
    """The reference mission's vehicles and settings, flown in another world between a_xy and b_xy."""
    ref = load_mission(REFERENCE)
    ends = {"A": tuple(map(float, a_xy)), "B": tuple(map(float, b_xy))}
    vehicles = tuple(replace(v, start_enu_m=ends[v.start], goal_enu_m=ends[v.goal]) for v in ref.vehicles)
    return replace(ref, world=world, stations=ends, vehicles=vehicles,
                   planner=replace(ref.planner, grid_resolution_m=resolution_m))


def signed_offset_m(a_xy, b_xy, points: np.ndarray) -> np.ndarray:
    """Signed distance of points from line a-b (+ left of a -> b)."""
    a = np.asarray(a_xy, float)
    d = (np.asarray(b_xy, float) - a) / math.dist(a_xy, b_xy)
    rel = np.asarray(points, float) - a
    return d[0] * rel[:, 1] - d[1] * rel[:, 0]


def densify(path: np.ndarray, step_m: float = 5.0) -> np.ndarray:
    line = LineString(path)
    return np.array([line.interpolate(s).coords[0] for s in np.arange(0.0, line.length, step_m)] + [path[-1]])


def away_from(points: np.ndarray, centres, radius_m: float) -> np.ndarray:
    keep = np.ones(len(points), dtype=bool)
    for c in centres:
        keep &= np.hypot(points[:, 0] - c[0], points[:, 1] - c[1]) > radius_m
    return points[keep]


def separation_m(points: np.ndarray, route: np.ndarray) -> float:
    line = LineString(route)
    return min((line.distance(Point(p)) for p in points), default=math.inf)


def test_reference_routes_lie_on_opposite_sides_of_a_b():
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    a, b = routes["a"], routes["b"]
    A, B = mission.stations["A"], mission.stations["B"]
    sep = mission.safety.min_separation_m
    exempt = sep + 2 * mission.planner.grid_resolution_m
    assert (a.constraint, b.constraint) == ("none", "opposite-side")
    a_pts = np.vstack([a.raw_enu_m, densify(a.sparse_enu_m)])
    b_pts = away_from(np.vstack([b.raw_enu_m, densify(b.sparse_enu_m)]), (A, B), exempt)
    side_a = np.sign(signed_offset_m(A, B, a_pts))
    assert set(side_a) <= {side_a[len(side_a) // 2], 0.0}  # a keeps to one side (touching at the ends)
    assert np.all(np.sign(signed_offset_m(A, B, b_pts)) == -side_a[len(side_a) // 2])
    assert separation_m(b_pts, a.sparse_enu_m) >= sep * 0.999
    # The paper's Fig. 4: hundreds of grid cells, a handful of key nodes.
    assert (a.nodes_raw, b.nodes_raw) == (406, 406)
    assert 3 <= a.nodes_sparse <= 6 and 3 <= b.nodes_sparse <= 7
    assert 4737.7 <= a.length_m <= 4737.7 * 1.01 and 4737.7 <= b.length_m <= 4737.7 * 1.02
    assert a.length_m == pytest.approx(path_length_m(a.sparse_enu_m))
    assert a.raw_length_m > a.length_m


def test_first_vehicle_gets_the_plain_a_star_route():
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    first = mission.by_priority[0]
    grid = rasterise(mission.world, mission.planner.grid_resolution_m)
    assert np.array_equal(routes[first.name].raw_enu_m, astar(grid, first.start_enu_m, first.goal_enu_m))


def _check_constraint_held(mission: Mission, routes: dict[str, Route]) -> None:
    a, b = routes["a"], routes["b"]
    A, B = mission.stations["A"], mission.stations["B"]
    sep = mission.safety.min_separation_m
    exempt = sep + 2 * mission.planner.grid_resolution_m + 1e-6
    b_pts = away_from(np.vstack([b.raw_enu_m, densify(b.sparse_enu_m)]), (A, B), exempt)
    if b.constraint in ("opposite-side", "avoid-route"):
        assert separation_m(b_pts, a.sparse_enu_m) >= sep * 0.999
    if b.constraint == "opposite-side":
        offsets = signed_offset_m(A, B, a.sparse_enu_m[1:-1])
        if np.all(offsets >= 0) or np.all(offsets <= 0):  # a keeps to one side: b to the other
            side = np.sign(offsets[np.argmax(np.abs(offsets))])
            assert np.all(np.sign(signed_offset_m(A, B, b_pts)) == -side)
        else:  # a weaves across A-B: b stays out of every lobe a encloses
            lobes = side_region(a.sparse_enu_m, mission.world.geofence)
            assert not any(lobes.contains(Point(p)) for p in b_pts)


@RANDOM
@given(worlds(min_obstacles=1, max_obstacles=5))
def test_random_worlds_keep_the_priority_rule_or_say_how_it_was_relaxed(world):
    A, B = (0.0, 0.0), (SIDE_M, SIDE_M)
    for st in (A, B):
        assume(all(o.inflated.distance(Point(st)) > 60.0 for o in world.obstacles))
    mission = mission_with(world, A, B)
    grid = rasterise(world, 20.0)
    try:
        routes = plan_routes(mission)
    except NoPath as exc:
        # Only when the plain grid has no route for that vehicle.
        assert exc.vehicle in ("a", "b")
        v = mission.vehicle(exc.vehicle)
        with pytest.raises(NoPath):
            astar(grid, v.start_enu_m, v.goal_enu_m)
        return
    assert routes["a"].constraint == "none"
    assert routes["b"].constraint in ("opposite-side", "avoid-route", "none")
    for r in routes.values():
        assert np.array_equal(r.sparse_enu_m[0], r.raw_enu_m[0]) and np.array_equal(r.sparse_enu_m[-1], r.raw_enu_m[-1])
        assert r.length_m <= r.raw_length_m + 1e-9
    _check_constraint_held(mission, routes)


def _wall_world(gap_m: float) -> World:
    """A wall across the diagonal A-B, with one opening of ``gap_m`` on the line itself."""
    # Two long thin rectangles along the anti-diagonal, past the geofence, either side of (500, 500).
    length = 800.0
    offset = (gap_m / 2.0 + length / 2.0) / math.sqrt(2.0)
    wall = [make_obstacle(f"w{i}", "rectangle", center=(500.0 + s * offset, 500.0 - s * offset),
                          width_m=length, height_m=10.0, rotation_deg=-45.0, inflation_ratio=0.0)
            for i, s in enumerate((1.0, -1.0))]
    return World(0.0, 0.0, 1000.0, 1000.0, 10.0, tuple(wall))


def test_narrow_opening_relaxes_to_no_constraint():
    # The only way through is a 60 m opening: b cannot keep 50 m from a's route in it.
    mission = mission_with(_wall_world(60.0), (100.0, 100.0), (900.0, 900.0), resolution_m=5.0)
    routes = plan_routes(mission)
    assert routes["b"].constraint == "none"
    assert LineString(routes["b"].raw_enu_m).distance(Point(500.0, 500.0)) < 30.0


def test_wide_opening_relaxes_to_avoid_route():
    # a goes straight through a 300 m opening on the line; there is no side to keep off, but
    # there is room for b to pass 50 m from a's route.
    mission = mission_with(_wall_world(300.0), (100.0, 100.0), (900.0, 900.0), resolution_m=5.0)
    routes = plan_routes(mission)
    assert routes["a"].nodes_sparse == 2
    assert routes["b"].constraint == "avoid-route"
    _check_constraint_held(mission, routes)


def test_blocked_far_side_relaxes_to_avoid_route():
    # A disc on the diagonal sends a around its north-west side; a wall from the disc to the
    # south-east corner closes the other side, so b must share a's side at a distance.
    disc = make_obstacle("disc", "circle", center=(500.0, 500.0), radius_m=100.0)
    wall = make_obstacle("wall", "polygon", vertices=[(500.0, 450.0), (1050.0, -60.0), (1070.0, -40.0), (520.0, 470.0)],
                         inflation_ratio=0.0)
    mission = mission_with(World(0.0, 0.0, 1000.0, 1000.0, 20.0, (disc, wall)), (100.0, 100.0), (900.0, 900.0),
                           resolution_m=10.0)
    routes = plan_routes(mission)
    assert np.all(signed_offset_m((100.0, 100.0), (900.0, 900.0), routes["a"].sparse_enu_m[1:-1]) > 0)
    assert routes["b"].constraint == "avoid-route"
    _check_constraint_held(mission, routes)


def test_walled_in_station_raises_no_path_naming_the_vehicle():
    ring = [make_obstacle(f"r{i}", "rectangle", center=c, width_m=w, height_m=h, inflation_ratio=0.0)
            for i, (c, w, h) in enumerate([((800.0, 700.0), 220.0, 20.0), ((800.0, 900.0), 220.0, 20.0),
                                           ((700.0, 800.0), 20.0, 220.0), ((900.0, 800.0), 20.0, 220.0)])]
    mission = mission_with(World(0.0, 0.0, 1000.0, 1000.0, 10.0, tuple(ring)), (100.0, 100.0), (800.0, 800.0), 10.0)
    with pytest.raises(NoPath) as err:
        plan_routes(mission)
    assert err.value.vehicle == "a"
    assert str(err.value).startswith("no path for vehicle 'a': goal (800.0, 800.0) unreachable") and "walled in" in str(err.value)


def test_budget_exceeded_names_the_vehicle():
    with pytest.raises(BudgetExceeded) as err:
        plan_routes(load_mission(REFERENCE), max_expansions=2)
    assert err.value.vehicle == "a" and "budget" in str(err.value)


def test_side_region_shapes():
    frame = box(-100.0, -100.0, 100.0, 100.0)
    left = side_region(np.array([[0.0, 0.0], [5.0, 10.0], [10.0, 0.0]]), frame)
    assert left.equals(box(-100.0, 0.0, 100.0, 100.0))
    right = side_region(np.array([[0.0, 0.0], [5.0, -10.0], [10.0, 0.0]]), frame)
    assert right.equals(box(-100.0, -100.0, 100.0, 0.0))
    weave = side_region(np.array([[0.0, 0.0], [10.0, 10.0], [20.0, -10.0], [30.0, 10.0], [40.0, 0.0]]), frame)
    assert weave.geom_type == "MultiPolygon" and weave.area == pytest.approx(200.0)
    assert side_region(np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]]), frame).is_empty


def test_detour_starts_where_the_vehicle_is_even_in_a_conservatively_occupied_cell():
    from companion.planning.routes import detour_route

    rock = make_obstacle("rock", "circle", center=(500.0, 500.0), radius_m=200.0)
    world = World(0.0, 0.0, 1000.0, 1000.0, 50.0, (rock,))
    grid = rasterise(world, 10.0)
    here = (500.0 + 240.5, 500.0)  # just outside the inflated disc (r = 240), in a cell the grid blocks
    assert not grid.is_free(*grid.world_to_cell(*here))
    route = detour_route(grid, world, here, (900.0, 950.0))
    assert tuple(route[0]) == here and tuple(route[-1]) == (900.0, 950.0)
    assert LineString(route).distance(Point(500.0, 500.0)) >= 240.0 - 1e-6  # clear of the inflated rock
    raw = detour_route(grid, world, here, (900.0, 950.0), sparse=False)
    assert len(raw) > len(route) and tuple(raw[0]) == here
    with pytest.raises(NoPath, match="no free grid cell"):
        detour_route(grid, world, (500.0, 500.0), (900.0, 950.0))  # the middle of the rock
