"""Occupancy grid and A*: conservative rasterisation, collision-free optimal paths, typed refusals."""

from __future__ import annotations

import heapq
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from shapely.geometry import LineString, Point

from uav_model.mission import load_mission
from companion.planning.astar import astar, path_length_m
from companion.planning.errors import BudgetExceeded, NoPath, PlanningError
from companion.planning.grid import OccupancyGrid, rasterise
from uav_model.world import World, make_obstacle
from world_strategies import points, worlds

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"
SQRT2 = math.sqrt(2.0)
RANDOM = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def brute_dijkstra(occupied: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> float | None:
    """Textbook Dijkstra over (ix, iy) with the same move rules; the cost in cells, None if unreachable."""
    ny, nx = occupied.shape

    def free(ix: int, iy: int) -> bool:
        return 0 <= ix < nx and 0 <= iy < ny and not occupied[iy, ix]

    dist = {start: 0.0}
    heap = [(0.0, start)]
    while heap:
        d, (ix, iy) = heapq.heappop(heap)
        if (ix, iy) == goal:
            return d
        if d > dist[(ix, iy)]:
            continue
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                if (dx, dy) == (0, 0) or not free(ix + dx, iy + dy):
                    continue
                if dx and dy and not (free(ix + dx, iy) and free(ix, iy + dy)):
                    continue
                nd = d + (SQRT2 if dx and dy else 1.0)
                if nd < dist.get((ix + dx, iy + dy), math.inf):
                    dist[(ix + dx, iy + dy)] = nd
                    heapq.heappush(heap, (nd, (ix + dx, iy + dy)))
    return None


def assert_grid_path_valid(grid: OccupancyGrid, path: np.ndarray, start, goal) -> float:
    """Endpoints exact; every step an 8-move between free cells, no corner cut. Returns the cell cost."""
    assert path.shape[1] == 2 and len(path) >= 2
    assert tuple(path[0]) == pytest.approx(start, abs=1e-12)
    assert tuple(path[-1]) == pytest.approx(goal, abs=1e-12)
    cells = [grid.world_to_cell(x, y) for x, y in path]
    assert cells[0] == grid.world_to_cell(*start) and cells[-1] == grid.world_to_cell(*goal)
    if cells[0] == cells[-1]:
        assert len(path) == 2
        return 0.0
    cost = 0.0
    for (ax, ay), (bx, by) in zip(cells, cells[1:]):
        dx, dy = bx - ax, by - ay
        assert max(abs(dx), abs(dy)) == 1, f"not an 8-neighbour move: {(ax, ay)} -> {(bx, by)}"
        assert grid.is_free(ax, ay) and grid.is_free(bx, by)
        if dx and dy:
            assert grid.is_free(ax + dx, ay) and grid.is_free(ax, ay + dy), "diagonal cuts an occupied corner"
        cost += SQRT2 if dx and dy else 1.0
    # Interior points are the cell centres themselves.
    for (x, y), (ix, iy) in zip(path[1:-1], cells[1:-1]):
        assert (x, y) == pytest.approx(grid.cell_to_world(ix, iy))
    return cost


@st.composite
def small_grids(draw):
    ny = draw(st.integers(2, 12))
    nx = draw(st.integers(2, 12))
    density = draw(st.integers(0, 6))  # tenths of the cells blocked, roughly
    occ = draw(arrays(bool, (ny, nx), elements=st.integers(0, 9).map(lambda v: v < density)))
    free_cells = np.argwhere(~occ)
    assume(len(free_cells) >= 2)
    i = draw(st.integers(0, len(free_cells) - 1))
    j = draw(st.integers(0, len(free_cells) - 1))
    assume(i != j)
    return occ, (int(free_cells[i][1]), int(free_cells[i][0])), (int(free_cells[j][1]), int(free_cells[j][0]))


@settings(max_examples=300, deadline=None)
@given(small_grids(), st.sampled_from(["octile", "euclidean"]))
def test_astar_is_optimal_and_legal_against_brute_dijkstra(astar_search, case, heuristic):
    occ, s, g = case
    grid = OccupancyGrid((-3.0, 7.0), 2.5, occ)
    start, goal = grid.cell_to_world(*s), grid.cell_to_world(*g)
    expected = brute_dijkstra(occ, s, g)
    if expected is None:
        with pytest.raises(NoPath, match="walled in"):
            astar(grid, start, goal, heuristic=heuristic)
        return
    path = astar(grid, start, goal, heuristic=heuristic)
    cost = assert_grid_path_valid(grid, path, start, goal)
    assert cost == pytest.approx(expected, rel=1e-12)
    assert path_length_m(path) == pytest.approx(expected * grid.resolution_m, rel=1e-9)


def _distance_to_inflated(world: World, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Exact distance from points to the union of inflated static obstacles (circles analytic)."""
    d = np.full(x.shape, np.inf)
    pts = shapely.points(x, y)
    for o in world.static_obstacles:
        if o.is_circle:
            d = np.minimum(d, np.maximum(0.0, np.hypot(x - o.center[0], y - o.center[1]) - o.inflated_radius_m))
        else:
            d = np.minimum(d, np.maximum(0.0, shapely.distance(o.footprint, pts) - o.margin_m))
    return d


@RANDOM
@given(worlds(), st.sampled_from([15.0, 25.0, 40.0]))
def test_rasterise_is_conservative_and_tight(world, resolution_m):
    grid = rasterise(world, resolution_m)
    xs, ys = grid.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    d = _distance_to_inflated(world, gx, gy)
    h = resolution_m * SQRT2 / 2.0
    # The keep-in: the declared area, within half a cell (a station on its edge keeps its cell).
    tol = resolution_m / 2.0 + 1e-9
    inside_keep_in = ((gx >= world.x_min_m - tol) & (gx <= world.x_max_m + tol)
                      & (gy >= world.y_min_m - tol) & (gy <= world.y_max_m + tol))
    free = ~grid.occupied
    assert np.all(d[free] > h), "a free cell centre lies within h of an inflated obstacle"
    assert np.all(inside_keep_in[free])
    # Not wildly conservative: occupied cells are near an obstacle (polygons dilate <= 0.12 % extra).
    occupied_by_obstacle = grid.occupied & inside_keep_in
    slack = 0.0013 * (max(o.margin_m for o in world.obstacles) + h)
    assert np.all(d[occupied_by_obstacle] <= h + slack)


@RANDOM
@given(worlds(), points(), points())
def test_astar_on_random_worlds_is_collision_free(world, start, goal):
    grid = rasterise(world, 20.0)
    assume(grid.is_free(*grid.world_to_cell(*start)) and grid.is_free(*grid.world_to_cell(*goal)))
    inflated = shapely.union_all([o.inflated for o in world.static_obstacles])
    try:
        path = astar(grid, start, goal)
    except NoPath as exc:
        assert "walled in" in str(exc)
        return
    assert_grid_path_valid(grid, path, start, goal)
    # Moves between cell centres never touch an inflated obstacle (the end legs start at the
    # exact station, which may sit up to half a cell off its centre, so they are not claimed).
    interior = LineString(path[1:-1]) if len(path) > 3 else None
    if interior is not None:
        assert not interior.intersects(inflated)


def test_reference_route_goes_around_the_fire_zone():
    mission = load_mission(REFERENCE)
    grid = rasterise(mission.world, mission.planner.grid_resolution_m)
    a, b = mission.stations["A"], mission.stations["B"]
    path = astar(grid, a, b)
    assert_grid_path_valid(grid, path, a, b)
    fire = mission.world.obstacles[0]
    clearance = np.hypot(path[:, 0] - fire.center[0], path[:, 1] - fire.center[1]) - fire.inflated_radius_m
    assert clearance.min() > 0
    # Never shorter than the tangent-arc-tangent optimum, and an octile path is at most 8.3 % longer.
    assert 4737.7 <= path_length_m(path) <= 4737.7 * 1.083


def test_walled_in_goal_raises_no_path(astar_search):
    world = World(0.0, 0.0, 1000.0, 1000.0, 0.0, ())
    ring = Point(700.0, 700.0).buffer(200.0).difference(Point(700.0, 700.0).buffer(120.0))
    grid = rasterise(world, 10.0, extra=[ring])
    with pytest.raises(NoPath) as err:
        astar(grid, (100.0, 100.0), (700.0, 700.0))
    assert type(err.value) is NoPath
    assert "walled in" in str(err.value) and "\n" not in str(err.value)
    assert err.value.vehicle is None


@pytest.mark.parametrize("which", ["start", "goal"])
def test_endpoint_inside_obstacle_is_refused_with_a_clear_message(which):
    world = World(0.0, 0.0, 1000.0, 1000.0, 0.0, (make_obstacle("o", "circle", center=(500.0, 500.0), radius_m=100.0),))
    grid = rasterise(world, 10.0)
    inside, outside = (500.0, 520.0), (50.0, 50.0)
    args = (inside, outside) if which == "start" else (outside, inside)
    with pytest.raises(NoPath, match=rf"^no path: {which} \(500.0, 520.0\) is inside an inflated obstacle"):
        astar(grid, *args)


@pytest.mark.parametrize("point, match", [((-500.0, 10.0), "outside the grid"),
                                          ((float("nan"), 10.0), "not a finite point")])
def test_bad_endpoints_are_refused(point, match):
    grid = OccupancyGrid((0.0, 0.0), 10.0, np.zeros((20, 20), dtype=bool))
    with pytest.raises(NoPath, match=match):
        astar(grid, point, (50.0, 50.0))


def test_budget_and_cancel_stop_the_search(astar_search):
    mission = load_mission(REFERENCE)
    grid = rasterise(mission.world, 10.0)
    a, b = mission.stations["A"], mission.stations["B"]
    with pytest.raises(BudgetExceeded, match="budget of 3"):
        astar(grid, a, b, max_expansions=3)
    with pytest.raises(BudgetExceeded, match="cancelled"):
        astar(grid, a, b, cancel=lambda: True)
    # A budget that suffices changes nothing.
    assert np.array_equal(astar(grid, a, b, max_expansions=10_000), astar(grid, a, b))


def test_same_cell_gives_the_two_points():
    grid = OccupancyGrid((0.0, 0.0), 10.0, np.zeros((3, 3), dtype=bool))
    path = astar(grid, (11.0, 12.0), (18.0, 19.0))
    assert path.tolist() == [[11.0, 12.0], [18.0, 19.0]]


def test_grid_coordinates_round_trip_and_immutability():
    occ = np.zeros((4, 5), dtype=bool)
    grid = OccupancyGrid((100.0, -50.0), 2.0, occ)
    occ[0, 0] = True  # the grid holds its own copy
    assert not grid.occupied[0, 0]
    assert grid.shape == (4, 5) and grid.extent_m == (100.0, -50.0, 110.0, -42.0)
    assert grid.cell_to_world(2, 3) == (105.0, -43.0)
    assert grid.world_to_cell(105.0, -43.0) == (2, 3)
    assert grid.world_to_cell(99.9, -50.0) == (-1, 0) and not grid.in_bounds(-1, 0)
    with pytest.raises(ValueError):
        grid.occupied[0, 0] = True
    mask = np.zeros((4, 5), dtype=bool)
    mask[1, 2] = True
    blocked = grid.with_blocked(mask)
    assert blocked.occupied[1, 2] and not grid.occupied[1, 2]
    with pytest.raises(PlanningError, match="shape"):
        grid.with_blocked(np.zeros((5, 4), dtype=bool))


@pytest.mark.parametrize("resolution", [0.0, -1.0, float("nan"), float("inf")])
def test_rasterise_refuses_bad_resolution(resolution):
    world = World(0.0, 0.0, 100.0, 100.0, 0.0, ())
    with pytest.raises(PlanningError, match="positive number of metres"):
        rasterise(world, resolution)


def test_rasterise_refuses_a_grid_too_large_to_search():
    world = World(0.0, 0.0, 100_000.0, 100_000.0, 0.0, ())
    with pytest.raises(PlanningError, match="coarser grid_resolution_m"):
        rasterise(world, 1.0)


def test_extra_line_geometry_blocks_a_band():
    world = World(0.0, 0.0, 100.0, 100.0, 0.0, ())
    grid = rasterise(world, 10.0, extra=[LineString([(0.0, 50.0), (100.0, 50.0)])])
    # Centres at y = 45 and 55 are 5 m < h = 7.07 m from the line; y = 35 and 65 are not.
    assert grid.occupied[4].all() and grid.occupied[5].all()
    assert not grid.occupied[3].any() and not grid.occupied[6].any()


def test_no_path_keeps_its_vehicle_and_type_across_pickling():
    err = BudgetExceeded("expansion budget of 5 spent", vehicle="b")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is BudgetExceeded and back.vehicle == "b" and str(back) == str(err)
    assert str(err) == "no path for vehicle 'b': expansion budget of 5 spent"
    assert NoPath("x").for_vehicle("a").vehicle == "a"
