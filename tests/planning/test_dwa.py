"""BDWA core: rollouts match the plant, commands stay in the window, chosen rollouts stay legal."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import shapely
import shapely.affinity
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from uav_model.frames import enu_heading_to_ned_yaw, ned_yaw_to_enu_heading
from companion.planning.dwa import (Command, DwaConfig, LocalGoals, NoLegalRollout, ObstacleSnapshot, OtherUav,
                                    Pose, heading_scores, inflated_clearance, plan_step, rollouts,
                                    sightline_scores)
from companion.planning.obstacle_field import ObstacleField, ObstacleTrack
from companion.planning.flight.loop import body_command
from uav_model.world import World, make_obstacle
from uav_model.plant import KinematicState, VehicleLimits, step

V, R = 10.0, 30.0


def config(**kw) -> DwaConfig:
    values = dict(speed_m_s=V, max_yaw_rate_rad_s=V / R, samples=31, dt_s=0.5, prediction_time_s=11.0,
                  w_h=0.37, w_d=0.6, w_s=0.8, sightline_cap_m=100.0, min_separation_m=55.0)
    values.update(kw)
    return DwaConfig(**values)


def snapshot(*obstacles, t_s: float = 0.0) -> ObstacleSnapshot:
    world = World(-1e4, -1e4, 1e4, 1e4, 0.0, tuple(obstacles))
    return ObstacleField.from_world(world).at_time(t_s)


EMPTY = ObstacleSnapshot.build([], [])


def test_rollout_shapes_follow_the_paper_window():
    cfg = config()
    assert cfg.steps == 22 and cfg.samples == 31
    assert cfg.yaw_rates_rad_s[0] == pytest.approx(-1 / 3) and cfg.yaw_rates_rad_s[-1] == pytest.approx(1 / 3)
    pts, heading = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    assert pts.shape == (31, 23, 2)
    assert pts[15, -1] == pytest.approx([110.0, 0.0])  # straight on: v * p
    assert heading[-1] == pytest.approx(11.0 / 3.0)  # a full-rate turn covers more than a U-turn
    steps = np.hypot(*np.diff(pts, axis=1).transpose(2, 0, 1))
    assert steps == pytest.approx(np.full((31, 22), 5.0))


@pytest.mark.parametrize("sample", [0, 7, 15, 24, 30])
def test_rollout_is_exactly_what_the_plant_flies(sample):
    cfg = config()
    pose = Pose(100.0, -50.0, math.radians(30))
    pts, heading = rollouts(pose, cfg)
    w = float(cfg.yaw_rates_rad_s[sample])
    state = KinematicState(north_m=pose.y_m, east_m=pose.x_m, down_m=-50.0,
                           vn_m_s=V * math.sin(pose.heading_rad), ve_m_s=V * math.cos(pose.heading_rad),
                           yaw_rad=enu_heading_to_ned_yaw(pose.heading_rad))
    limits = VehicleLimits(V, V / R, 8.0)
    for k in range(1, cfg.steps + 1):
        state = step(state, body_command(w, V), limits, cfg.dt_s)
        assert (state.east_m, state.north_m) == pytest.approx(tuple(pts[sample, k]), abs=1e-6)
    assert math.cos(ned_yaw_to_enu_heading(state.yaw_rad) - heading[sample]) == pytest.approx(1.0)


def test_open_field_heads_straight_for_the_goal():
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, EMPTY, config())
    assert isinstance(result, Command)
    assert result.yaw_rate_rad_s == 0.0 and result.speed_m_s == V
    assert result.heading_score == pytest.approx(180.0)
    assert result.legal_count == 31


def test_turns_toward_a_goal_on_the_left():
    result = plan_step(Pose(0.0, 0.0, 0.0), (500.0, 500.0), None, EMPTY, config())
    assert result.yaw_rate_rad_s > 0.0  # ENU: counter-clockwise is positive


def test_boxed_in_is_a_typed_result_not_an_exception():
    # An inflated disk right ahead: every rollout's first steps go into it.
    wall = make_obstacle("wall", "circle", center=(40.0, 0.0), radius_m=30.0)
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, snapshot(wall), config())
    assert isinstance(result, NoLegalRollout)
    assert "(obstacle)" in result.reason
    assert result.escape is None  # hovering in front of a static disk is safe: hold


def test_boxed_in_by_the_other_uav_is_reported():
    other = OtherUav(20.0, 0.0, 0.0, 0.0)  # already inside the separation, and nothing gets further
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), other, EMPTY, config(samples=1))
    assert isinstance(result, NoLegalRollout) and "separation" in result.reason


def test_escape_when_hovering_would_be_hit_by_a_moving_obstacle():
    field = ObstacleField.from_world(World(-1e4, -1e4, 1e4, 1e4, 0.0, ()))
    # An unknown intruder (a 150 m disc) 270 m behind, closing at 30 m/s: its true body catches
    # every rollout within the horizon, a hovering vehicle after 4 s, one flying straight on after 6 s.
    snap = field.from_tracks([ObstacleTrack("intruder", -270.0, 0.0, 30.0, 0.0)])
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, snap, config())
    assert isinstance(result, NoLegalRollout) and result.escape is not None
    assert "escaping: clear for 6 s, hovering for 4 s" in result.reason
    assert result.escape.yaw_rate_rad_s == 0.0 and result.escape.speed_m_s == V


def test_geofence_is_a_keep_in_rule():
    cfg = config(fence_m=(-1000.0, -1000.0, 60.0, 1000.0))  # the fence 60 m ahead
    result = plan_step(Pose(0.0, 0.0, 0.0), (5000.0, 0.0), None, EMPTY, cfg)
    assert isinstance(result, Command) and abs(result.yaw_rate_rad_s) > 0.1
    pts, _ = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    chosen = pts[int(np.argmin(np.abs(cfg.yaw_rates_rad_s - result.yaw_rate_rad_s)))]
    assert chosen[:, 0].max() <= 60.0


def test_a_vehicle_inside_the_margin_may_leave_but_not_go_deeper():
    disk = make_obstacle("d", "circle", center=(0.0, 0.0), radius_m=100.0)  # inflated to 120
    pose = Pose(0.0, 110.0, 0.0)  # 10 m deep in the margin, flying east along it
    snap = snapshot(disk)
    result = plan_step(pose, (0.0, 1000.0), None, snap, config())
    assert isinstance(result, Command)
    pts, _ = rollouts(pose, config())
    chosen = int(np.argmin(np.abs(config().yaw_rates_rad_s - result.yaw_rate_rad_s)))
    assert np.all(np.hypot(pts[chosen, :, 0], pts[chosen, :, 1]) >= 110.0 - 1e-6)


def test_other_uav_rollouts_inside_separation_are_discarded():
    cfg = config()
    other = OtherUav(120.0, 0.0, -10.0, 0.0)  # head-on, 120 m away, closing at 20 m/s
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), other, EMPTY, cfg)
    assert isinstance(result, Command) and result.yaw_rate_rad_s != 0.0
    pts, _ = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    chosen = int(np.argmin(np.abs(cfg.yaw_rates_rad_s - result.yaw_rate_rad_s)))
    ox = other.x_m + other.vx_m_s * cfg.times_s
    assert np.min(np.hypot(pts[chosen, :, 0] - ox, pts[chosen, :, 1])) >= cfg.min_separation_m


# --- sightline -------------------------------------------------------------------------------

def test_sightline_through_a_disk_is_the_smaller_side():
    disk = make_obstacle("d", "circle", center=(0.0, 30.0), radius_m=100.0)
    ends = np.array([[-500.0, 0.0], [-500.0, 400.0], [-500.0, -95.0]])
    s = sightline_scores(ends, (500.0, 0.0), 0.0, snapshot(disk))
    assert s[0] == pytest.approx(70.0)  # centre 30 m left of the line: min(130, 70)
    assert s[1] == 0.0  # a segment that misses the disk
    assert s[2] > 0.0  # tilted line still crossing


def test_sightline_polygon_extent_left_and_right_and_segment_ends():
    square = make_obstacle("sq", "rectangle", center=(0.0, 0.0), width_m=100.0, height_m=100.0)
    snap = snapshot(square)
    s = sightline_scores(np.array([[-300.0, 20.0], [-300.0, 20.0]]), (300.0, 20.0), 0.0, snap)
    assert s[0] == pytest.approx(30.0)  # 70 m below the line, 30 m above: the smaller
    # The same line, but the segment stops before the square: nothing crosses.
    short = sightline_scores(np.array([[-300.0, 20.0]]), (-100.0, 20.0), 0.0, snap)
    assert short[0] == 0.0


def test_sightline_takes_the_largest_of_several_obstacles_and_predicts_moving_ones():
    a = make_obstacle("a", "circle", center=(-200.0, 0.0), radius_m=50.0)
    b = make_obstacle("b", "circle", center=(200.0, 10.0), radius_m=80.0)
    snap = snapshot(a, b)
    assert sightline_scores(np.array([[-500.0, 0.0]]), (500.0, 0.0), 0.0, snap)[0] == pytest.approx(70.0)
    # A disk 300 m south, moving north at 10 m/s, is on the line 30 s later.
    field = ObstacleField.from_world(World(-1e4, -1e4, 1e4, 1e4, 0.0, ()))
    moving = field.from_tracks([ObstacleTrack("m", 0.0, -300.0, 0.0, 10.0)])
    assert sightline_scores(np.array([[-500.0, 0.0]]), (500.0, 0.0), 0.0, moving)[0] == 0.0
    assert sightline_scores(np.array([[-500.0, 0.0]]), (500.0, 0.0), 30.0, moving)[0] == pytest.approx(150.0)


def test_bdwa_prefers_keeping_the_sight_line_blocked():
    # Goal straight ahead, the other UAV off to the right. Flying straight on, the sight line
    # passes in front of a small disk; bending right puts the disk between them. Without the
    # sightline term the planner flies straight.
    disk = make_obstacle("d", "circle", center=(200.0, -250.0), radius_m=60.0)
    other = OtherUav(600.0, -600.0, 0.0, 0.0)
    snap = snapshot(disk)
    with_s = plan_step(Pose(0.0, 0.0, 0.0), (2000.0, 0.0), other, snap, config(w_s=0.8))
    without = plan_step(Pose(0.0, 0.0, 0.0), (2000.0, 0.0), other, snap, config(w_s=0.0))
    assert without.sightline_score == 0.0 and without.yaw_rate_rad_s == 0.0
    assert with_s.sightline_score > 0.0 and with_s.yaw_rate_rad_s < 0.0


# --- heading critic ----------------------------------------------------------------------------

def test_heading_score_is_180_minus_the_deviation_at_the_prediction_point():
    cfg = config()
    pts, heading = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    h = heading_scores(pts, heading, LocalGoals.single((1000.0, 0.0)))
    assert h[15] == pytest.approx(180.0)
    assert np.all((h >= 0.0) & (h <= 180.0))
    behind = heading_scores(pts, heading, LocalGoals.single((-1000.0, 0.0)))
    assert behind[15] == pytest.approx(0.0)


def test_rollouts_that_reach_a_node_are_scored_toward_the_next_one():
    cfg = config()
    pts, heading = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    node, after = (60.0, 0.0), (60.0, 1000.0)
    plain = heading_scores(pts, heading, LocalGoals.single(node))
    window = LocalGoals(np.array([node, after]), (-100.0, 0.0), 30.0, 20.0, ends_at_station=True)
    ahead = heading_scores(pts, heading, window)
    assert plain[15] == pytest.approx(0.0)  # straight on overshoots the node: the paper's critic hates it
    assert ahead[15] > 80.0  # scored toward the next node instead
    assert np.argmax(ahead) > 15  # and the best rollout turns left, toward it


def test_reaching_the_station_inside_the_horizon_scores_full_marks():
    cfg = config()
    pts, heading = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    window = LocalGoals(np.array([[50.0, 0.0]]), (-100.0, 0.0), 30.0, 20.0, ends_at_station=True)
    assert heading_scores(pts, heading, window)[15] == 180.0


def test_goal_behind_turns_one_way_without_chattering():
    cfg = config()
    x, y, th = 0.0, 0.0, 0.0
    goal = (-1500.0, 1.0)
    signs = []
    for _ in range(90):
        result = plan_step(Pose(x, y, th), goal, None, EMPTY, cfg)
        err = (math.atan2(goal[1] - y, goal[0] - x) - th + math.pi) % (2 * math.pi) - math.pi
        if abs(err) > math.pi / 2:
            signs.append(np.sign(result.yaw_rate_rad_s))
        th += result.yaw_rate_rad_s * cfg.dt_s
        x += V * cfg.dt_s * math.cos(th)
        y += V * cfg.dt_s * math.sin(th)
    assert len(set(s for s in signs if s != 0)) == 1
    err = (math.atan2(goal[1] - y, goal[0] - x) - th + math.pi) % (2 * math.pi) - math.pi
    assert abs(err) < math.radians(10)


# --- properties over random worlds -------------------------------------------------------------

shapes = st.sampled_from(["circle", "rectangle", "triangle", "polygon"])


@st.composite
def obstacles(draw):
    kind = draw(shapes)
    cx, cy = draw(st.floats(-300, 300)), draw(st.floats(-300, 300))
    size = draw(st.floats(10, 150))
    rot = draw(st.floats(0, 360))
    if kind == "circle":
        o = make_obstacle("o", kind, center=(cx, cy), radius_m=size)
    elif kind == "rectangle":
        o = make_obstacle("o", kind, center=(cx, cy), width_m=size * 1.4, height_m=size, rotation_deg=rot)
    elif kind == "triangle":
        o = make_obstacle("o", kind, center=(cx, cy), circumradius_m=size, rotation_deg=rot)
    else:  # a non-convex "L"
        s = size
        verts = [(cx, cy), (cx + s, cy), (cx + s, cy + s / 3), (cx + s / 3, cy + s / 3), (cx + s / 3, cy + s), (cx, cy + s)]
        o = make_obstacle("o", kind, vertices=verts, rotation_deg=rot)
    return o


@st.composite
def worlds(draw):
    obs = draw(st.lists(obstacles(), min_size=1, max_size=5))
    named = [o.__class__(id=f"o{i}", kind=o.kind, center=o.center, size_m=o.size_m, footprint=o.footprint,
                         margin_m=o.margin_m) for i, o in enumerate(obs)]
    return World(-1e4, -1e4, 1e4, 1e4, 0.0, tuple(named))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(world=worlds(), heading=st.floats(-math.pi, math.pi), gx=st.floats(-2000, 2000), gy=st.floats(-2000, 2000),
       moving=st.lists(st.tuples(st.floats(-400, 400), st.floats(-400, 400), st.floats(-8, 8), st.floats(-8, 8)),
                       max_size=2))
def test_command_in_window_and_chosen_rollout_never_enters_an_inflated_obstacle(world, heading, gx, gy, moving):
    pose = Pose(0.0, 0.0, heading)
    if any(o.inflated.intersects(Point(0.0, 0.0)) for o in world.obstacles):
        return  # starting inside is covered by its own test
    field = ObstacleField.from_world(world)
    tracks = [ObstacleTrack(f"m{i}", x, y, vx, vy) for i, (x, y, vx, vy) in enumerate(moving)
              if math.hypot(x, y) > field.unknown_radius_m * 1.2 + 1.0]
    snap = field.from_tracks(tracks)
    cfg = config()
    result = plan_step(pose, (gx, gy), None, snap, cfg)
    if isinstance(result, NoLegalRollout):
        return
    assert abs(result.yaw_rate_rad_s) <= V / R + 1e-12
    assert result.speed_m_s == V
    pts, _ = rollouts(pose, cfg)
    chosen = pts[int(np.argmin(np.abs(cfg.yaw_rates_rad_s - result.yaw_rate_rad_s)))]
    for o in world.obstacles:  # independent check on shapely geometry
        assert not shapely.contains_xy(o.inflated, chosen[:, 0], chosen[:, 1]).any()
    for tr in tracks:  # unknown intruders: discs predicted at constant velocity
        cx = tr.x_m + tr.vx_m_s * cfg.times_s
        cy = tr.y_m + tr.vy_m_s * cfg.times_s
        assert np.all(np.hypot(chosen[:, 0] - cx, chosen[:, 1] - cy) >= field.unknown_radius_m * 1.2 - 1e-6)


@settings(max_examples=200, deadline=None)
@given(world=worlds(), x=st.floats(-500, 500), y=st.floats(-500, 500))
def test_clearance_matches_shapely(world, x, y):
    snap = ObstacleField.from_world(world).at_time(0.0)
    got = inflated_clearance(np.array([x]), np.array([y]), np.zeros(1), snap)[:, 0]
    p = Point(x, y)
    for value, oid in zip(got, snap.ids):
        o = next(o for o in world.obstacles if o.id == oid)
        true = o.footprint.exterior.distance(p) * (-1.0 if o.footprint.contains(p) else 1.0)
        if o.is_circle:  # the footprint polygon is a 128-gon; compare with the exact circle
            true = math.hypot(x - o.center[0], y - o.center[1]) - o.size_m
            assert value == pytest.approx(true - o.margin_m, abs=1e-6)
        else:
            assert value == pytest.approx(true - o.margin_m, abs=1e-6)


def test_point_level_with_a_vertex_is_not_counted_inside():
    # Found by Hypothesis: a vertex at y = 2.7e-67, the point at y = 0 left of the polygon.
    ell = make_obstacle("l", "polygon", vertices=[(0, 2.677e-67), (0, 10), (10 / 3, 10), (10 / 3, 10 / 3),
                                                  (10, 10 / 3), (10, 2.677e-67)])
    got = inflated_clearance(np.array([-1.0, 2.0]), np.array([0.0, 2.0]), np.zeros(2), snapshot(ell))[0]
    inner = ell.footprint.exterior.distance(Point(2.0, 2.0))
    assert got == pytest.approx([1.0 - ell.margin_m, -inner - ell.margin_m])


def test_snapshots_with_different_polygon_sizes_merge():
    tri = make_obstacle("tri", "triangle", center=(0.0, 0.0), circumradius_m=50.0)
    world = World(-1e4, -1e4, 1e4, 1e4, 0.0, (tri,))
    field = ObstacleField.from_world(world)
    merged = field.from_tracks([ObstacleTrack("disc", 300.0, 0.0, 0.0, 0.0)])
    assert merged.ids == ("disc", "tri")
    pentagon = ObstacleSnapshot.build([], [("pent", np.array([[500, 0], [600, 0], [650, 80], [550, 150], [450, 80]]),
                                            10.0, 1.0, 0.0)])
    both = merged.merged(pentagon)
    assert both.poly_a_m.shape == (2, 5, 2)
    assert len(both.vertices(0)) == 3 and len(both.vertices(1)) == 5
    d = inflated_clearance(np.array([0.0, 550.0]), np.array([0.0, 50.0]), np.zeros(2), both)
    assert d[1, 0] < 0 and d[1, 1] > 0  # rows: disc, tri, pent. (0, 0) is inside the triangle
    assert d[2, 0] > 0 and d[2, 1] < 0  # and (550, 50) inside the pentagon


@settings(max_examples=100, deadline=None)
@given(x=st.floats(-400, 400), y=st.floats(-400, 400), t=st.floats(0, 11), vx=st.floats(-10, 10), vy=st.floats(-10, 10))
def test_moving_polygon_is_predicted_at_constant_velocity(x, y, t, vx, vy):
    cart = make_obstacle("cart", "rectangle", center=(0.0, 0.0), width_m=120.0, height_m=60.0, rotation_deg=25.0)
    field = ObstacleField.from_world(World(-1e4, -1e4, 1e4, 1e4, 0.0, ()))
    field = ObstacleField(field.static, {"cart": cart}, 0.2, 150.0)
    snap = field.from_tracks([ObstacleTrack("cart", 10.0, -20.0, vx, vy)])
    got = inflated_clearance(np.array([x]), np.array([y]), np.array([t]), snap)[0, 0]
    moved = shapely.affinity.translate(cart.footprint, 10.0 + vx * t, -20.0 + vy * t)
    p = Point(x, y)
    true = moved.exterior.distance(p) * (-1.0 if moved.contains(p) else 1.0)
    assert got == pytest.approx(true - cart.margin_m, abs=1e-6)


def test_culled_snapshot_keeps_exactly_the_obstacles_in_reach():
    near_disk = make_obstacle("near", "circle", center=(100.0, 0.0), radius_m=20.0)
    far_disk = make_obstacle("far", "circle", center=(5000.0, 0.0), radius_m=20.0)
    near_box = make_obstacle("box", "rectangle", center=(0.0, 120.0), width_m=40.0, height_m=40.0)
    far_tri = make_obstacle("tri", "triangle", center=(0.0, -5000.0), circumradius_m=40.0)
    snap = snapshot(near_disk, far_disk, near_box, far_tri)
    culled = snap.near(0.0, 0.0, 120.0, 11.0)
    assert culled.ids == ("near", "box")
    assert snap.near(0.0, 0.0, 120.0, 11.0) is culled  # cached for the next tick
    pts = np.array([10.0, 50.0, -30.0]), np.array([0.0, 60.0, 90.0])
    full = inflated_clearance(*pts, np.zeros(3), snap)
    assert inflated_clearance(*pts, np.zeros(3), culled) == pytest.approx(full[[0, 2]])
    fresh = snapshot(near_disk, near_box)
    assert inflated_clearance(*pts, np.zeros(3), fresh) == pytest.approx(full[[0, 2]])
    assert snap.near(0.0, 0.0, 10.0, 0.0).count == 0


def test_merged_snapshot_equals_a_freshly_built_one():
    tri = ("tri", np.array([[0.0, 0.0], [50.0, 0.0], [25.0, 40.0]]), 8.0, 0.0, 0.0)
    pent = ("pent", np.array([[500, 0], [600, 0], [650, 80], [550, 150], [450, 80]], dtype=float), 10.0, 1.0, -2.0)
    c1 = ("c1", 100.0, 100.0, 20.0, 4.0, 0.0, 0.0)
    c2 = ("c2", -300.0, 50.0, 30.0, 6.0, 3.0, 1.0)
    merged = ObstacleSnapshot.build([c1], [tri]).merged(ObstacleSnapshot.build([c2], [pent]))
    fresh = ObstacleSnapshot.build([c1, c2], [tri, pent])
    for f in dataclasses.fields(ObstacleSnapshot):
        if f.name != "_subsets":
            a, b = getattr(merged, f.name), getattr(fresh, f.name)
            assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name


# --- when no rollout is legal: spin recovery, hold, escape -----------------------------------------

def test_boxed_in_by_a_static_wall_yaws_in_place_toward_a_free_heading_then_flies():
    # The disk ahead blocks every cruise rollout. A multicopter turns round on the spot (speed 0,
    # full yaw rate, the plant's own model) until a heading has a legal rollout, then flies it.
    wall = make_obstacle("wall", "circle", center=(60.0, 0.0), radius_m=40.0)
    snap, cfg = snapshot(wall), config()
    pose = Pose(0.0, 0.0, 0.0)
    state = KinematicState(north_m=0.0, east_m=0.0, down_m=-50.0, yaw_rad=enu_heading_to_ned_yaw(0.0))
    limits = VehicleLimits(max_speed_m_s=V, max_yaw_rate_rad_s=V / R, max_accel_m_s2=8.0)
    spins = 0
    for _ in range(40):
        result = plan_step(pose, (-1000.0, 300.0), None, snap, cfg)
        if isinstance(result, Command):
            break
        assert isinstance(result, NoLegalRollout) and result.recovery is not None and result.escape is None
        assert result.recovery.speed_m_s == 0.0 and abs(result.recovery.yaw_rate_rad_s) == pytest.approx(V / R)
        assert "recovering" in result.reason
        spins += 1
        state = step(state, body_command(result.recovery.yaw_rate_rad_s, 0.0), limits, cfg.dt_s)
        pose = Pose(state.east_m, state.north_m, ned_yaw_to_enu_heading(state.yaw_rad))
    assert isinstance(result, Command) and result.speed_m_s == V
    assert spins >= 2 and math.hypot(pose.x_m, pose.y_m) < 1e-6  # turned where it stood (it started at rest)
    assert abs(pose.heading_rad) > math.radians(20)  # no longer facing the wall


def test_no_recovery_when_disabled_holds_as_before():
    wall = make_obstacle("wall", "circle", center=(60.0, 0.0), radius_m=40.0)
    result = plan_step(Pose(0.0, 0.0, 0.0), (-1000.0, 300.0), None, snapshot(wall), config(recovery_samples=0))
    assert isinstance(result, NoLegalRollout) and result.recovery is None and result.escape is None


def test_a_hover_point_on_a_moving_obstacles_path_is_not_a_hold():
    # Boxed in by a static wall ahead, and an unknown intruder (a 150 m disc) coming from the
    # left at 15 m/s: its inflated body is clear of the hover point for longer than the 11 s
    # horizon, so the old rule held; it reaches the hover point within a spin plus a horizon.
    wall = make_obstacle("wall", "circle", center=(60.0, 0.0), radius_m=40.0)
    world = World(-1e4, -1e4, 1e4, 1e4, 0.0, (wall,))
    snap = ObstacleField.from_world(world).from_tracks([ObstacleTrack("intruder", 0.0, 420.0, 0.0, -15.0)])
    hover = inflated_clearance(np.zeros(23), np.zeros(23), np.arange(23) * 0.5, snap)
    assert hover.min() > 0.0  # the hover point is clear for the whole 11 s horizon ...
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, snap, config())
    assert isinstance(result, NoLegalRollout)
    assert result.recovery is not None or result.escape is not None  # ... but holding is not safe
    calm = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, snapshot(wall), config(recovery_samples=0))
    assert isinstance(calm, NoLegalRollout) and calm.escape is None  # without the intruder: hold


def test_sightline_is_dropped_once_the_other_uav_has_arrived():
    # The same geometry as test_bdwa_prefers_keeping_the_sight_line_blocked, with the other UAV
    # parked at its station: nothing to hide from, so the planner flies as plain DWA would ...
    disk = make_obstacle("d", "circle", center=(200.0, -250.0), radius_m=60.0)
    snap = snapshot(disk)
    parked = OtherUav(600.0, -600.0, 0.0, 0.0, arrived=True)
    result = plan_step(Pose(0.0, 0.0, 0.0), (2000.0, 0.0), parked, snap, config(w_s=0.8))
    assert result.sightline_score == 0.0 and result.yaw_rate_rad_s == 0.0
    # ... but the parked UAV is still kept clear of (separation is not dropped).
    blocking = OtherUav(60.0, 0.0, 0.0, 0.0, arrived=True)
    boxed = plan_step(Pose(0.0, 0.0, 0.0), (2000.0, 0.0), blocking, EMPTY, config(samples=1, recovery_samples=0))
    assert isinstance(boxed, NoLegalRollout) and "separation" in boxed.reason


def test_an_escape_keeps_the_most_clearance_of_the_rollouts_that_last_longest():
    """Seed 2027 i054: b escaped along a static disc's true footprint at 0-9 m and, lagging its
    commands, hit it; seed 2026 i115: 22 s of escapes, each trading 5-15 m of clearance to a
    static disc for heading, ratcheted b into the disc. Of the rollouts clear of the true
    footprints for the whole horizon the escape takes the one that keeps the most clearance;
    straight ahead, the best heading, would keep 2 m of the disc."""
    disc = make_obstacle("s", "circle", center=(60.0, 102.0), radius_m=100.0)  # inflated to 120
    field = ObstacleField.from_world(World(-1e4, -1e4, 1e4, 1e4, 0.0, (disc,)))
    snap = field.from_tracks([ObstacleTrack("intruder", -240.0, 0.0, 16.0, 0.0)])  # hovering is hit
    cfg = config(recovery_samples=0)
    result = plan_step(Pose(0.0, 0.0, 0.0), (1000.0, 0.0), None, snap, cfg)
    assert isinstance(result, NoLegalRollout) and "escaping: clear for the horizon" in result.reason
    pts, _ = rollouts(Pose(0.0, 0.0, 0.0), cfg)
    t = np.tile(cfg.dt_s * np.arange(pts.shape[1]), len(pts))
    margins = np.concatenate([snap.circle_margin_m, snap.poly_margin_m])[:, None]
    true = (inflated_clearance(pts[..., 0].ravel(), pts[..., 1].ravel(), t, snap) + margins).min(axis=0)
    kept = true.reshape(len(pts), -1)[:, 1:].min(axis=1)  # each rollout's least true clearance
    i = int(np.argmin(np.abs(cfg.yaw_rates_rad_s - result.escape.yaw_rate_rad_s)))
    straight = int(np.argmin(np.abs(cfg.yaw_rates_rad_s)))
    assert kept[i] == pytest.approx(kept[kept >= 0.0].max()) and kept[straight] < 5.0 < kept[i]
