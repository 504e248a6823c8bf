"""Flying a timed route (issue 10, seed 11's diagnosis): along the timed path, not the A* route;
slowed when ahead of the plan however far; timed against where the vehicles above really are;
the sightline term only near the planned closest approach."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.planning.dwa import NO_OBSTACLES, OtherUav, Pose
from companion.planning.local_goals import LocalGoalTracker
from companion.planning.routes import plan_routes
from companion.planning.coordination.clocks import PriorityClocks, sight_near_m
from companion.planning.coordination.timed import closest_approach_m, forecast
from companion.planning.timed_route import TimedRoute
from companion.planning.vehicle_planner import VehiclePlanner
from tests.planning.test_speed_window import V, _fly, timed_config
from uav_model.mission import load_mission

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"
EAST = np.array([[0.0, 0.0], [1000.0, 0.0]])


def test_target_speed_is_measured_along_the_route_and_is_zero_however_far_ahead():
    route = forecast("b", EAST, 10.0)  # the plan is at x = 10 t
    xy = np.array([[300.0, 0.0], [100.0, 0.0], [140.0, 0.0], [700.0, 5.0]])
    t = np.array([10.0, 10.0, 10.0, 10.0])
    np.testing.assert_allclose(route.lead_m(xy, t), [200.0, 0.0, 40.0, 600.0])
    # 200 m ahead: wait (it used to fly cruise back toward a point behind it); on plan: cruise;
    # 40 m ahead: 10 m to the plan's place 5 s later, 2 m/s; far ahead and off the path: wait.
    np.testing.assert_allclose(route.target_speed_at(xy, t, 10.0), [0.0, 10.0, 2.0, 0.0])
    along, off = route.progress_at(np.array([[250.0, -30.0]]))
    np.testing.assert_allclose([along[0], off[0]], [250.0, 30.0])


def test_a_vehicle_ahead_of_its_schedule_is_slowed_and_arrives_on_time():
    # The plan flies from x = -200 at 4 m/s from t = -25: at t = 0 it is at x = -100, the vehicle
    # 100 m ahead at x = 0, at cruise (10 m/s). The plan reaches the station at t = 175 s.
    route = forecast("x", np.array([[-200.0, 0.0], [600.0, 0.0]]), 4.0, start_s=-25.0)
    arrived, commands, planner = _fly(timed_config(), (600.0, 0.0), 20.0, 300.0, route, replan_after_s=10.0)
    speeds = np.array([0.0 if c is None else c.speed_m_s for c in commands])
    assert arrived is not None and arrived >= 0.9 * 175.0, arrived  # not ~60 s at cruise
    assert speeds[20:].mean() < 0.6 * V
    assert planner.detours == 0  # waiting for the plan is no stall


def test_the_timed_variant_walks_its_timed_path_and_the_paper_variant_its_route():
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    b = mission.by_priority[1]
    start, goal = np.asarray(b.start_enu_m), np.asarray(b.goal_enu_m)
    side = np.array([start[0], goal[1]])  # an L through another corner than A*'s route
    timed = TimedRoute("b", np.array([0.0, 10.0, 200.0, 400.0]), np.vstack([start, start, side, goal]))
    planner = VehiclePlanner.build(mission, b, routes["b"], "astar-bdwa-timed", timed_route=timed)
    np.testing.assert_allclose(planner.tracker.nodes, [start, side, goal])  # the wait's repeat dropped
    paper = VehiclePlanner.build(mission, b, routes["b"], "astar-bdwa", timed_route=timed)
    np.testing.assert_allclose(paper.tracker.nodes, routes["b"].sparse_enu_m)


def test_the_lower_vehicle_is_timed_by_the_higher_ones_progress_and_the_first_by_sim_time():
    routes = {"a": forecast("a", EAST, 10.0), "b": forecast("b", np.array([[0.0, 100.0], [0.0, 1100.0]]), 10.0)}
    clocks = PriorityClocks(routes, ["a", "b"])
    for t in np.arange(0.0, 30.0, 0.5):  # a flies at half its planned speed
        clocks.observe("a", (5.0 * t, 0.0), t)
        clocks.observe("b", (0.0, 100.0 + 10.0 * t), t)
        tau_a, tau_b = clocks.now("a", t), clocks.now("b", t)
    assert tau_a == pytest.approx(29.5)  # a waits for nobody
    assert tau_b == pytest.approx(14.75 + 2.0, abs=0.6)  # b's plan is read where a really is (+ slack)
    clocks.done("a")
    assert clocks.now("b", 31.0) == pytest.approx(31.0)


def test_the_sightline_term_acts_only_near_the_planned_closest_approach():
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    a, b = mission.by_priority
    timed = {a.name: forecast(a.name, routes[a.name].sparse_enu_m, a.speed_m_s),
             b.name: forecast(b.name, routes[b.name].sparse_enu_m, b.speed_m_s)}
    near = sight_near_m(mission, timed, b.name)
    assert sight_near_m(mission, timed, a.name) is None
    assert near == pytest.approx(closest_approach_m(timed[a.name], timed[b.name]) + 200.0)
    planner = VehiclePlanner.build(mission, b, routes[b.name], "astar-bdwa-timed", timed_route=timed[b.name],
                                   sight_near_m=near)
    x, y = timed[b.name].planned_position_at(100.0)
    pose = Pose(float(x), float(y), 0.0)
    far = OtherUav(x + near + 100.0, y, 0.0, 0.0)
    alone = VehiclePlanner.build(mission, b, routes[b.name], "astar-bdwa-timed", timed_route=timed[b.name])
    # beyond the near distance the other UAV changes nothing (no sightline term; separation far)
    assert planner.tick(pose, far, NO_OBSTACLES, 100.0).command == alone.tick(pose, None, NO_OBSTACLES, 100.0).command


def test_local_goals_advance_with_the_progress_along_the_timed_path_past_a_cut_corner():
    """A space-time path can step out and back (beside a wait, round a shadow's edge); the
    multicopter cuts the corner, and the paper's tracker kept the node it never reached as the
    goal, so b turned back to it and hovered 10 s or more near the closest approach (seed 13, a tuning
    seed). With a timed path the goal is past wherever the vehicle is along the path."""
    xy = np.array([[0.0, 0.0], [200.0, 0.0], [190.0, 30.0], [210.0, 0.0], [600.0, 0.0]])
    route = TimedRoute("x", np.array([0.0, 20.0, 23.2, 26.8, 65.8]), xy)
    timed = VehiclePlanner("x", timed_config(), LocalGoalTracker(route.path_xy, 5.0), 20.0, None, route)
    timed.tick(Pose(205.0, 2.0, 0.0), None, NO_OBSTACLES, 26.0)
    assert timed.tracker.goal_xy == (210.0, 0.0)
    paper = VehiclePlanner("x", timed_config(), LocalGoalTracker(xy, 5.0), 20.0)
    paper.tick(Pose(205.0, 2.0, 0.0), None, NO_OBSTACLES, 26.0)
    assert paper.tracker.goal_xy == (190.0, 30.0)  # the paper's rule: reached or passed


def test_advance_to_passes_every_node_no_farther_along_and_never_the_station():
    tracker = LocalGoalTracker(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]]), 1.0)
    assert tracker.advance_to(5.0) == (10.0, 0.0)
    assert tracker.advance_to(20.0) == (30.0, 0.0)
    assert tracker.advance_to(1e9) == (30.0, 0.0) and tracker.is_last
    assert tracker.advance_to(0.0) == (30.0, 0.0)  # never back
