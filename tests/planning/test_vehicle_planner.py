"""The vehicle planner and A*-BDWA fusion: local-goal switching, variant wiring, obstacle snapshots from world or tracks."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest

from uav_model.mission import load_mission, parse_mission
from companion.planning.dwa import Command, OtherUav, Pose, inflated_clearance
from companion.planning.local_goals import LocalGoalTracker
from companion.planning.obstacle_field import ObstacleField, ObstacleTrack, snapshot_at, snapshot_from_tracks
from companion.planning.vehicle_planner import VehiclePlanner

NODES = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [300.0, 100.0]])


def test_tracker_starts_at_the_first_node_after_the_start():
    tracker = LocalGoalTracker(NODES, 30.0)
    assert tracker.update(0.0, 0.0) == (100.0, 0.0)
    assert tracker.index == 1


def test_tracker_switches_inside_the_acceptance_radius():
    tracker = LocalGoalTracker(NODES, 30.0)
    assert tracker.update(60.0, 20.0) == (100.0, 0.0)  # 45 m away, not past
    assert tracker.update(75.0, 10.0) == (100.0, 100.0)  # 27 m away


def test_tracker_switches_once_the_node_is_passed_even_far_off_the_segment():
    tracker = LocalGoalTracker(NODES, 30.0)
    assert tracker.update(101.0, -200.0) == (100.0, 100.0)  # projection beyond node 1


def test_tracker_skips_several_nodes_in_one_update():
    tracker = LocalGoalTracker(NODES, 30.0)
    assert tracker.update(110.0, 95.0) == (300.0, 100.0)
    assert tracker.is_last


def test_tracker_never_passes_the_station():
    tracker = LocalGoalTracker(NODES, 30.0)
    tracker.update(110.0, 95.0)
    assert tracker.update(900.0, 100.0) == (300.0, 100.0)
    assert tracker.update(300.0, 100.0) == (300.0, 100.0)


def test_tracker_refuses_a_single_node():
    with pytest.raises(ValueError):
        LocalGoalTracker(np.array([[0.0, 0.0]]), 30.0)


def test_window_holds_the_nodes_a_rollout_can_reach():
    tracker = LocalGoalTracker(NODES, 30.0)
    near = tracker.window(50.0, 0.0, 140.0, 20.0)  # node 1 at 50 m, node 2 at 150 m of path
    assert near.nodes_xy.tolist() == [[100.0, 0.0], [100.0, 100.0]]
    assert near.prev_xy == (0.0, 0.0) and not near.ends_at_station
    far = tracker.window(50.0, 0.0, 1000.0, 20.0)
    assert len(far.nodes_xy) == 3 and far.ends_at_station


# --- variants ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Route:  # the shape of routes.Route that the planner reads
    raw_enu_m: np.ndarray
    sparse_enu_m: np.ndarray


REF = load_mission("missions/paper_reference.yaml")
ROUTE = _Route(np.array([[0.0, 0.0], [10.0, 10.0], [20.0, 20.0], [3181.98, 3181.98]]),
               np.array([[0.0, 0.0], [20.0, 20.0], [3181.98, 3181.98]]))


@pytest.mark.parametrize(("variant", "nodes"), [
    ("astar-bdwa", ROUTE.sparse_enu_m), ("astar-bdwa-nosparse", ROUTE.raw_enu_m),
    ("bdwa", np.array([[0.0, 0.0], [3181.98, 3181.98]])), ("dwa", np.array([[0.0, 0.0], [3181.98, 3181.98]])),
])
def test_variant_picks_its_local_goals(variant, nodes):
    planner = VehiclePlanner.build(REF, REF.vehicle("a"), ROUTE, variant)
    assert np.array_equal(planner.tracker.nodes, nodes)


def test_sightline_weight_by_variant_and_priority():
    b = REF.vehicle("b")
    assert VehiclePlanner.build(REF, b, ROUTE, "astar-bdwa").config.w_s == pytest.approx(0.8)
    assert VehiclePlanner.build(REF, b, None, "bdwa").config.w_s == pytest.approx(0.8)
    assert VehiclePlanner.build(REF, b, None, "dwa").config.w_s == 0.0
    # a has right of way: it does not trade flight time for sightline
    assert VehiclePlanner.build(REF, REF.vehicle("a"), ROUTE, "astar-bdwa").config.w_s == 0.0


def test_no_progress_for_replan_after_s_plans_a_detour_from_where_the_vehicle_is():
    planner = VehiclePlanner.build(REF, REF.vehicle("a"), ROUTE, "astar-bdwa")
    stuck = Pose(2000.0, 400.0, 0.0)  # hovering in place: the remaining route never shortens
    t = 0.0
    while not planner.detour_due:
        planner.tick(stuck, None, ObstacleField.from_world(REF.world).static, t)
        t += 0.5
        assert t <= 60.5, "a vehicle stuck for replan_after_s must ask for a new route"
    assert t == pytest.approx(60.5)  # asked at t = 60 s exactly, 60 s after the first tick
    nodes = planner.plan_detour(stuck.x_m, stuck.y_m)
    assert tuple(nodes[0]) == (2000.0, 400.0) and nodes[-1] == pytest.approx(REF.vehicle("a").goal_enu_m)
    assert planner.adopt_detour(nodes, stuck.x_m, stuck.y_m, t) and planner.detours == 1
    assert not planner.detour_due and np.array_equal(planner.tracker.nodes, nodes)
    planner.tick(stuck, None, ObstacleField.from_world(REF.world).static, t + 30.0)
    assert not planner.detour_due  # the clock restarted at the detour


def test_progress_or_a_variant_without_a_global_route_never_replans():
    field = ObstacleField.from_world(REF.world).static
    flying = VehiclePlanner.build(REF, REF.vehicle("a"), ROUTE, "astar-bdwa")
    for k in range(300):  # 150 s along the diagonal at 10 m/s
        flying.tick(Pose(20.0 + 5.0 * k * 0.7071, 20.0 + 5.0 * k * 0.7071, math.pi / 4), None, field, 0.5 * k)
    assert not flying.detour_due
    for variant in ("bdwa", "dwa"):
        station_only = VehiclePlanner.build(REF, REF.vehicle("a"), None, variant)
        assert station_only.detour_policy is None and station_only.plan_detour(1000.0, 400.0) is None
    never = VehiclePlanner.build(dataclasses.replace(REF, planner=dataclasses.replace(REF.planner, replan_after_s=0.0)),
                                 REF.vehicle("a"), ROUTE, "astar-bdwa")
    assert never.detour_policy is None


def test_config_comes_from_the_mission():
    cfg = VehiclePlanner.build(REF, REF.vehicle("a"), ROUTE, "astar-bdwa").config
    assert (cfg.samples, cfg.dt_s, cfg.prediction_time_s) == (31, 0.5, 11.0)
    assert (cfg.w_h, cfg.w_d) == (pytest.approx(0.37), pytest.approx(0.6))
    assert cfg.max_yaw_rate_rad_s == pytest.approx(1 / 3)
    assert cfg.min_separation_m == pytest.approx(50.0 + 5.0)


def test_astar_variant_without_a_route_is_refused():
    with pytest.raises(ValueError, match="needs an A\\* route"):
        VehiclePlanner.build(REF, REF.vehicle("a"), None, "astar-bdwa")


def test_tick_commands_then_holds_for_good_on_arrival():
    planner = VehiclePlanner.build(REF, REF.vehicle("a"), None, "bdwa")
    field = ObstacleField.from_world(REF.world)
    first = planner.tick(Pose(0.0, 0.0, np.pi / 4), OtherUav(3000.0, 3000.0, -7.0, -7.0), field.at_time(0.0), 0.0)
    assert isinstance(first.command, Command) and not first.arrived and first.planner_ms > 0
    arrived = planner.tick(Pose(3175.0, 3170.0, np.pi / 4), None, field.at_time(1.0), 1.0)
    assert arrived.arrived and arrived.command is None and arrived.speed_m_s == 0.0
    again = planner.tick(Pose(3000.0, 3000.0, 0.0), None, field.at_time(2.0), 2.0)
    assert again.arrived  # frozen: it does not take off again


# --- snapshots -----------------------------------------------------------------------------------

MOVING = parse_mission("""
area: {x_min_m: 0, y_min_m: 0, x_max_m: 2000, y_max_m: 2000}
stations: {A: [0, 0], B: [2000, 2000]}
obstacles:
  - {id: rock, shape: triangle, center: [1000, 1000], circumradius_m: 200}
  - {id: cart, shape: rectangle, center: [500, 1500], width_m: 100, height_m: 60,
     motion: {type: shuttle, to: [1500, 1500], speed_m_s: 5}}
  - {id: drone, shape: circle, center: [1500, 500], radius_m: 80,
     motion: {type: orbit, pivot: [1500, 800], speed_m_s: 4}}
vehicles:
  - {name: a, start: A, goal: B}
""", "moving")


def test_headless_snapshot_is_the_true_state_now():
    field = ObstacleField.from_world(MOVING.world)
    snap = field.at_time(40.0)
    assert set(snap.ids) == {"rock", "cart", "drone"}
    cart = MOVING.world.obstacles[1]
    i = snap.poly_ids.index("cart")
    verts = snap.vertices(i)
    assert sorted(map(tuple, verts.round(6))) == sorted(map(tuple, cart.footprint_at(40.0).exterior.coords[:-1]))
    assert snap.poly_vel_m_s[i] == pytest.approx([5.0, 0.0])
    j = snap.circle_ids.index("drone")
    assert tuple(snap.circle_xy_m[j]) == pytest.approx(MOVING.world.obstacles[2].center_at(40.0))
    assert tuple(snap.circle_vel_m_s[j]) == pytest.approx(MOVING.world.obstacles[2].motion.velocity_at(40.0))


MOVING_DISCS = parse_mission("""
area: {x_min_m: 0, y_min_m: 0, x_max_m: 2000, y_max_m: 2000}
stations: {A: [0, 0], B: [2000, 2000]}
obstacles:
  - {id: rock, shape: triangle, center: [1000, 1000], circumradius_m: 200}
  - {id: pond, shape: circle, center: [400, 400], radius_m: 150}
  - {id: wall, shape: rectangle, center: [1500, 1400], width_m: 300, height_m: 80}
  - {id: drone, shape: circle, center: [1500, 500], radius_m: 80,
     motion: {type: orbit, pivot: [1500, 800], speed_m_s: 4}}
  - {id: kite, shape: circle, center: [300, 1200], radius_m: 60,
     motion: {type: shuttle, to: [1300, 1200], speed_m_s: 5}}
vehicles:
  - {name: a, start: A, goal: B}
""", "moving_discs")

_SNAPSHOT_ARRAYS = ("circle_xy_m", "circle_radius_m", "circle_margin_m", "circle_vel_m_s", "poly_a_m", "poly_b_m",
                    "poly_d_m", "poly_margin_m", "poly_centre_m", "poly_bound_m", "poly_vel_m_s", "bound_xy_m",
                    "bound_radius_m", "speed_m_s", "poly_inv_len2", "poly_dx_per_dy")


@pytest.mark.parametrize("mission", [MOVING, MOVING_DISCS], ids=["moving-polygon", "moving-discs-only"])
def test_culled_subsets_of_tick_snapshots_equal_those_of_one_snapshot_per_time(mission):
    """The runner's snapshots share culled subsets of unmoved obstacles across ticks: each must
    still equal the subset culled from a snapshot built for that time alone."""
    field = ObstacleField.from_world(mission.world)
    times = 0.5 * np.arange(0, 1200, 23)
    probes = [(x, y) for x in (300.0, 1000.0, 1450.0) for y in (450.0, 1200.0, 1500.0)]
    for t, fast in zip(times, field.at_times(times)):
        slow = field.at_time(float(t))
        for x, y in probes:
            for got, want in ((fast.near(x, y, 150.0, 11.0), slow.near(x, y, 150.0, 11.0)),
                              (fast.near(x, y, 120.0, 11.0, to_xy=(1800.0, 300.0)),
                               slow.near(x, y, 120.0, 11.0, to_xy=(1800.0, 300.0)))):
                assert got.ids == want.ids and got.polygons_move == want.polygons_move, (t, x, y)
                for name in _SNAPSHOT_ARRAYS:
                    assert getattr(got, name) == pytest.approx(getattr(want, name), abs=1e-9), (t, x, y, name)


@pytest.mark.parametrize("mission", [MOVING, MOVING_DISCS], ids=["moving-polygon", "moving-discs-only"])
def test_snapshots_for_all_tick_times_equal_one_snapshot_per_time(mission):
    field = ObstacleField.from_world(mission.world)
    times = 0.5 * np.arange(0, 900, 37)  # both shuttle legs, the orbit all round
    for t, fast in zip(times, field.at_times(times)):
        slow = field.at_time(float(t))
        assert fast.ids == slow.ids and fast.polygons_move == slow.polygons_move
        for name in ("circle_xy_m", "circle_vel_m_s", "poly_a_m", "poly_b_m", "poly_d_m", "poly_centre_m",
                     "poly_vel_m_s", "bound_xy_m", "bound_radius_m", "speed_m_s"):
            assert getattr(fast, name) == pytest.approx(getattr(slow, name), abs=1e-9), (t, name)
        probe = np.array([500.0, 900.0, 1500.0]), np.array([1500.0, 1000.0, 700.0])
        assert inflated_clearance(*probe, np.full(3, 3.0), fast) == pytest.approx(
            inflated_clearance(*probe, np.full(3, 3.0), slow), abs=1e-9)


def test_live_snapshot_from_tracks_places_known_shapes_and_guards_unknown_intruders():
    snap = snapshot_from_tracks(MOVING.world, [("cart", 800.0, 1500.0, -5.0, 0.0),
                                               ObstacleTrack("stranger", 100.0, 100.0, 1.0, 2.0)])
    i = snap.poly_ids.index("cart")
    verts = snap.vertices(i)
    assert len(verts) == 4 and verts.mean(axis=0) == pytest.approx([800.0, 1500.0])
    j = snap.circle_ids.index("stranger")
    assert snap.circle_radius_m[j] == 150.0 and snap.circle_margin_m[j] == pytest.approx(30.0)
    assert "drone" not in snap.ids  # not reported, not known: the static world only
    assert snapshot_at(MOVING.world, 40.0).ids == ObstacleField.from_world(MOVING.world).at_time(40.0).ids


def test_tick_flies_the_escape_when_hovering_is_worse():
    planner = VehiclePlanner.build(REF, REF.vehicle("a"), None, "dwa")
    field = ObstacleField.from_world(REF.world)
    snap = field.from_tracks([ObstacleTrack("intruder", 1000.0, 2300.0, 0.0, -30.0)])  # from behind, fast
    result = planner.tick(Pose(1000.0, 2000.0, -np.pi / 2), None, snap, 0.0)
    assert result.command is not None and result.hold_reason is None
    assert result.escape_reason is not None and "escaping" in result.escape_reason
