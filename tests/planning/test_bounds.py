"""Lower bounds: the paper's 4737.7 m, straight lines, and a bound that is a bound on random worlds."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from uav_model.mission import load_mission
from companion.planning.astar import astar, path_length_m
from companion.planning.bounds import disk_detour_m, lower_bound_m, lower_bound_s
from companion.planning.errors import NoPath, PlanningError
from companion.planning.grid import rasterise
from companion.planning.sparse import sparsify
from uav_model.world import World, make_obstacle
from world_strategies import points, worlds

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"
RANDOM = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def test_reference_bound_is_the_tangent_arc_tangent_optimum():
    mission = load_mission(REFERENCE)
    a, b = mission.stations["A"], mission.stations["B"]
    assert lower_bound_m(mission.world, a, b) == pytest.approx(4737.7, abs=0.5)
    assert lower_bound_m(mission.world, b, a) == pytest.approx(4737.7, abs=0.5)  # direction-free
    assert lower_bound_s(mission.world, a, b, 10.0) == pytest.approx(473.77, abs=0.05)


def test_general_case_on_the_reference_stays_just_below_the_closed_form():
    mission = load_mission(REFERENCE)
    a, b = mission.stations["A"], mission.stations["B"]
    # A small obstacle far off the route forces the visibility-graph path.
    aside = make_obstacle("aside", "rectangle", center=(3000.0, 200.0), width_m=50.0, height_m=50.0)
    world = replace(mission.world, obstacles=mission.world.obstacles + (aside,))
    closed = disk_detour_m(a, b, mission.world.obstacles[0].center, 600.0)
    general = lower_bound_m(world, a, b)
    assert closed * (1 - 5e-4) <= general <= closed


def test_straight_line_when_nothing_is_in_the_way():
    empty = World(0.0, 0.0, 1000.0, 1000.0, 0.0, ())
    assert lower_bound_m(empty, (0.0, 0.0), (300.0, 400.0)) == 500.0
    off_route = World(0.0, 0.0, 1000.0, 1000.0, 0.0,
                      (make_obstacle("c", "circle", center=(800.0, 100.0), radius_m=50.0),
                       make_obstacle("t", "triangle", center=(100.0, 800.0), circumradius_m=50.0)))
    assert lower_bound_m(off_route, (0.0, 0.0), (1000.0, 1000.0)) == pytest.approx(1000.0 * math.sqrt(2.0))
    one_disc_aside = World(0.0, 0.0, 1000.0, 1000.0, 0.0, (make_obstacle("c", "circle", center=(800.0, 100.0), radius_m=50.0),))
    assert lower_bound_m(one_disc_aside, (0.0, 0.0), (1000.0, 1000.0)) == pytest.approx(1000.0 * math.sqrt(2.0))


def test_square_corners_by_hand():
    square = make_obstacle("sq", "rectangle", center=(0.0, 0.0), width_m=2.0, height_m=2.0, inflation_ratio=0.0)
    world = World(-5.0, -5.0, 5.0, 5.0, 0.0, (square,))
    assert lower_bound_m(world, (-3.0, 0.0), (3.0, 0.0)) == pytest.approx(2.0 + 2.0 * math.sqrt(5.0), rel=1e-12)
    assert lower_bound_m(world, (-3.0, -3.0), (3.0, 3.0)) == pytest.approx(2.0 * math.sqrt(4.0 + 16.0), rel=1e-12)


def test_inflated_square_by_hand():
    # A 2 x 2 square inflated by r: tangent to the round corner at (-1, 1), arc, the top edge, and back.
    r = 0.5
    square = make_obstacle("sq", "rectangle", center=(0.0, 0.0), width_m=2.0, height_m=2.0,
                           inflation_ratio=r / math.sqrt(2.0))
    world = World(-5.0, -5.0, 5.0, 5.0, 0.0, (square,))
    sc = math.sqrt(5.0)                                   # |start - corner|, start (-3, 0), corner (-1, 1)
    theta = math.acos(-1.0 / sc)                          # between corner->start and straight up
    exact = 2.0 * (math.sqrt(sc * sc - r * r) + r * (theta - math.acos(r / sc))) + 2.0
    bound = lower_bound_m(world, (-3.0, 0.0), (3.0, 0.0))
    assert exact * (1 - 5e-4) <= bound <= exact


def test_disk_detour_closed_form_pieces():
    # Symmetric case: tangents of sqrt(d^2 - R^2) each and the arc between the tangent points.
    d, r = 1000.0, 600.0
    half_arc = math.pi / 2 - math.acos(r / d)
    assert disk_detour_m((-d, 0.0), (d, 0.0), (0.0, 0.0), r) == pytest.approx(2 * math.sqrt(d * d - r * r) + 2 * r * half_arc)
    assert disk_detour_m((-d, 700.0), (d, 700.0), (0.0, 0.0), r) == pytest.approx(2 * d)  # passes above
    with pytest.raises(PlanningError, match="inside the disc"):
        disk_detour_m((0.0, 10.0), (d, 0.0), (0.0, 0.0), r)


@RANDOM
@given(worlds(), points(), points())
def test_random_bound_is_a_bound(world, start, goal):
    """Between the straight line and any feasible route; never below a single disc's detour."""
    assume(all(o.inflated.distance(Point(p)) > 45.0 for o in world.obstacles for p in (start, goal)))
    try:
        bound = lower_bound_m(world, start, goal)
    except NoPath:
        with pytest.raises(NoPath):
            astar(rasterise(world, 20.0), start, goal)
        return
    assert bound >= math.dist(start, goal) - 1e-9
    for o in world.static_obstacles:
        if o.is_circle:
            assert bound >= disk_detour_m(start, goal, o.center, o.inflated_radius_m) * (1 - 5e-4)
        # Adding obstacles never shortens the bound.
        assert bound >= lower_bound_m(replace(world, obstacles=(o,)), start, goal) * (1 - 5e-4)
    try:
        raw = astar(rasterise(world, 20.0), start, goal)
    except NoPath:
        return
    assert bound <= path_length_m(sparsify(raw, world)) + 1e-6


def test_bad_inputs_are_refused():
    world = World(0.0, 0.0, 1000.0, 1000.0, 0.0,
                  (make_obstacle("t", "triangle", center=(500.0, 500.0), circumradius_m=100.0),
                   make_obstacle("c", "circle", center=(100.0, 900.0), radius_m=50.0)))
    with pytest.raises(PlanningError, match=r"start \(500.0, 500.0\) is inside an inflated obstacle"):
        lower_bound_m(world, (500.0, 500.0), (0.0, 0.0))
    with pytest.raises(PlanningError, match="not a finite point"):
        lower_bound_m(world, (0.0, 0.0), (math.nan, 0.0))
    with pytest.raises(PlanningError, match="positive number of m/s"):
        lower_bound_s(world, (0.0, 0.0), (10.0, 0.0), 0.0)


def test_walled_in_goal_has_no_bound():
    ring = tuple(make_obstacle(f"r{i}", "rectangle", center=c, width_m=w, height_m=h, inflation_ratio=0.0)
                 for i, (c, w, h) in enumerate([((800.0, 700.0), 220.0, 20.0), ((800.0, 900.0), 220.0, 20.0),
                                                ((700.0, 800.0), 20.0, 220.0), ((900.0, 800.0), 20.0, 220.0)]))
    world = World(0.0, 0.0, 1000.0, 1000.0, 10.0, ring)
    with pytest.raises(NoPath, match="walled in"):
        lower_bound_m(world, (100.0, 100.0), (800.0, 800.0))


@pytest.mark.parametrize("speed", [5.0, 10.0, 20.0])
def test_time_bound_scales_with_speed(speed):
    mission = load_mission(REFERENCE)
    a, b = mission.stations["A"], mission.stations["B"]
    assert lower_bound_s(mission.world, a, b, speed) * speed == pytest.approx(lower_bound_m(mission.world, a, b))


@given(st.floats(100.0, 900.0), st.floats(0.0, 3.0))
@settings(max_examples=30, deadline=None)
def test_bound_is_symmetric_in_start_and_goal(x, angle):
    world = World(0.0, 0.0, 1000.0, 1000.0, 0.0,
                  (make_obstacle("t", "triangle", center=(500.0, 500.0), circumradius_m=150.0, rotation_deg=math.degrees(angle)),
                   make_obstacle("c", "circle", center=(300.0, 700.0), radius_m=80.0)))
    s, g = (x, 0.0), (1000.0 - x, 1000.0)
    assert lower_bound_m(world, s, g) == pytest.approx(lower_bound_m(world, g, s), rel=1e-9)
