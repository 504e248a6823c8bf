"""Sparse optimisation: clearance kept, never longer, the paper's circle test is the general rule."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, box

from uav_model.mission import load_mission
from companion.planning.astar import astar, path_length_m
from companion.planning.errors import NoPath, PlanningError
from companion.planning.grid import rasterise
from companion.planning.sparse import paper_circle_redundant, sparsify
from uav_model.world import World, make_obstacle
from world_strategies import points, worlds

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"
RESOLUTION_M = 20.0
RANDOM = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def segment_clearance_m(world: World, a, b) -> float:
    """Exact distance from segment ab to the nearest inflated static obstacle (<= 0: touches it)."""
    seg = LineString([a, b]) if tuple(a) != tuple(b) else Point(a)
    gaps = []
    for o in world.static_obstacles:
        if o.is_circle:
            gaps.append(seg.distance(Point(o.center)) - o.inflated_radius_m)
        else:
            gaps.append(seg.distance(o.footprint) - o.margin_m)
    return min(gaps, default=math.inf)


def point_clearance_m(world: World, p) -> float:
    return segment_clearance_m(world, p, p)


def raw_route(world: World, start, goal) -> np.ndarray:
    # Stations well off the obstacles, as missions require: then the legs from the exact
    # station to the first cell centre are clear too (see astar's docstring).
    assume(point_clearance_m(world, start) > 2.2 * RESOLUTION_M)
    assume(point_clearance_m(world, goal) > 2.2 * RESOLUTION_M)
    try:
        return astar(rasterise(world, RESOLUTION_M), start, goal)
    except NoPath:
        assume(False)
        raise


def index_in(raw: np.ndarray, sparse: np.ndarray) -> list[int]:
    """Indices of the sparse nodes in the raw path; asserts they form an increasing subsequence."""
    out, j = [], 0
    for node in sparse:
        while j < len(raw) and not np.array_equal(raw[j], node):
            j += 1
        assert j < len(raw), "a sparse node is not a node of the raw path (or is out of order)"
        out.append(j)
        j += 1
    return out


@RANDOM
@given(worlds(), points(), points(), st.sampled_from([0.0, 5.0]))
def test_sparse_keeps_clearance_is_shorter_and_follows_the_rule(world, start, goal, clearance_m):
    raw = raw_route(world, start, goal)
    sparse = sparsify(raw, world, clearance_m=clearance_m)
    assert np.array_equal(sparse[0], raw[0]) and np.array_equal(sparse[-1], raw[-1])
    assert path_length_m(sparse) <= path_length_m(raw) + 1e-9
    kept = index_in(raw, sparse)
    for (i, j) in zip(kept, kept[1:]):
        gap = segment_clearance_m(world, raw[i], raw[j])
        assert gap > 0, f"sparse segment {raw[i]} -> {raw[j]} enters an inflated obstacle"
        if j > i + 1:  # a shortcut (not a raw segment) keeps the requested clearance
            assert gap > clearance_m - 1e-9
    # Each kept interior node is needed: the shortcut over it is not clear (the rule, not any subsequence).
    # (Polygons are checked dilated by at most 0.12 % extra, hence the slack.)
    slack = 0.0013 * max(o.margin_m for o in world.obstacles) + 1e-6
    for i, k in zip(kept, kept[1:-1]):
        assert segment_clearance_m(world, raw[i], raw[k + 1]) <= clearance_m + slack


@RANDOM
@given(worlds(), points(), points())
def test_polygon_input_shortcuts_miss_the_polygons(world, start, goal):
    raw = raw_route(world, start, goal)
    polygons = [o.inflated for o in world.static_obstacles]
    sparse = sparsify(raw, polygons)
    kept = index_in(raw, sparse)
    union = shapely.union_all(polygons)
    for i, j in zip(kept, kept[1:]):
        if j > i + 1:
            assert not LineString([raw[i], raw[j]]).intersects(union)


def test_reference_route_collapses_to_a_few_key_nodes():
    mission = load_mission(REFERENCE)
    raw = astar(rasterise(mission.world, 10.0), mission.stations["A"], mission.stations["B"])
    sparse = sparsify(raw, mission.world)
    assert len(raw) > 300 and 3 <= len(sparse) <= 6
    # Within 1 % of the tangent-arc-tangent optimum (4737.7 m); never below it.
    assert 4737.7 <= path_length_m(sparse) <= 4737.7 * 1.01


def test_extra_geometry_is_respected():
    world = World(0.0, 0.0, 1000.0, 1000.0, 0.0, ())
    wall = box(480.0, 0.0, 520.0, 700.0)
    raw = astar(rasterise(world, 10.0, extra=[wall]), (100.0, 100.0), (900.0, 100.0))
    sparse = sparsify(raw, world, extra=[wall])
    assert len(sparse) >= 3
    assert not LineString(sparse).intersects(wall)
    assert len(sparsify(raw, world)) == 2  # without the wall, a straight shot


@pytest.mark.parametrize("bad, match", [(np.zeros((3, 3)), "shape"), (np.array([[0.0, 0.0], [np.nan, 1.0]]), "non-finite")])
def test_bad_paths_are_refused(bad, match):
    with pytest.raises(PlanningError, match=match):
        sparsify(bad, [])


def test_two_node_path_is_returned_unchanged():
    p = np.array([[0.0, 0.0], [5.0, 5.0]])
    out = sparsify(p, [Point(2.0, 2.0).buffer(1.0)])
    assert np.array_equal(out, p) and out is not p


# --- the paper's circle test is the general rule on circles ---------------------------------

def _circle_world(radius_m: float) -> World:
    return World(-2000.0, -2000.0, 2000.0, 2000.0, 0.0,
                 (make_obstacle("O", "circle", center=(0.0, 0.0), radius_m=radius_m, inflation_ratio=0.2),))


coords = st.floats(-1500.0, 1500.0)


# 100 drawn triples: the figure's cases (test_paper_circle_test_cases_from_the_figure) pin the
# obtuse, acute-and-cutting and acute-and-clear angles; 400 cost a minute on a loaded machine.
@settings(max_examples=100, deadline=None)
@given(st.floats(20.0, 500.0), st.tuples(coords, coords), st.tuples(coords, coords), st.tuples(coords, coords))
def test_paper_circle_test_agrees_with_the_general_rule(radius_m, a, mid, b):
    assume(min(math.dist(a, mid), math.dist(mid, b)) > 1.0)
    world = _circle_world(radius_m)
    safe = world.obstacles[0].inflated_radius_m
    disc = Point(0.0, 0.0)
    # A valid path: nodes outside the circle, legs a-mid and mid-b clear of it (not grazing).
    assume(LineString([a, mid]).distance(disc) > safe * (1 + 1e-9))
    assume(LineString([mid, b]).distance(disc) > safe * (1 + 1e-9))
    assume(abs(LineString([a, b]).distance(disc) - safe) > 1e-6 * safe)  # no exact tangency
    general = len(sparsify(np.array([a, mid, b]), world)) == 2
    assert paper_circle_redundant(a, mid, b, (0.0, 0.0), safe) == general


@settings(max_examples=100, deadline=None)
@given(st.floats(20.0, 500.0), st.tuples(coords, coords), st.tuples(coords, coords), st.floats(0.05, 0.95))
def test_paper_circle_test_collinear_nodes_are_redundant(radius_m, a, b, t):
    assume(math.dist(a, b) > 1.0)  # a real path leg, not a degenerate one GEOS measures oddly
    world = _circle_world(radius_m)
    safe = world.obstacles[0].inflated_radius_m
    assume(LineString([a, b]).distance(Point(0.0, 0.0)) > safe * (1 + 1e-9))
    mid = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
    assert paper_circle_redundant(a, mid, b, (0.0, 0.0), safe)
    assert len(sparsify(np.array([a, mid, b]), world)) == 2


def test_paper_circle_test_cases_from_the_figure():
    # Obtuse angle at A_x: the segment's closest point to O is A_x -> redundant.
    assert paper_circle_redundant((700.0, 0.0), (800.0, 300.0), (1000.0, 500.0), (0.0, 0.0), 600.0)
    # Both base angles acute and the chord passes 100 m from O -> keep the middle node.
    assert not paper_circle_redundant((-800.0, -100.0), (0.0, -700.0), (800.0, -100.0), (0.0, 0.0), 600.0)
    # Acute angles but the chord passes 650 m from O -> redundant.
    assert paper_circle_redundant((-800.0, -650.0), (0.0, -900.0), (800.0, -650.0), (0.0, 0.0), 600.0)
