"""Headless runner end to end: the paper's reference flight, dodging moving obstacles and each
other, and failing safe (a timeout, never a collision) when the local planner is trapped."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from shapely.geometry import LineString, Point

from uav_model.mission import load_mission, parse_mission
from companion.planning.flight.headless import simulate

REFERENCE_BOUND_S = 473.8  # SPEC §1: tangent + arc + tangent around the 600 m disk, at 10 m/s


@pytest.fixture
def reference(reference_flight):
    return reference_flight  # one headless reference flight per process (tests/conftest.py)


def test_reference_mission_succeeds_near_the_physical_bound(reference):
    s = reference.summary
    assert s.success, s.reason
    a, b = s.vehicles["a"], s.vehicles["b"]
    assert a.arrived and b.arrived
    assert a.lower_bound_s == pytest.approx(REFERENCE_BOUND_S, abs=0.05)
    assert a.lower_bound_s <= a.flight_time_s <= 1.02 * a.lower_bound_s
    assert b.flight_time_s >= b.lower_bound_s
    assert a.min_obstacle_clearance_m > 100.0 - 1e-6  # never inside the 20 % margin
    assert s.min_separation_m >= 50.0
    assert a.nodes_sparse < a.nodes_raw


def test_reference_tracks_are_the_plant_at_constant_speed(reference):
    for name, tr in reference.tracks.items():
        steps = np.hypot(np.diff(tr.x_m), np.diff(tr.y_m))
        assert steps == pytest.approx(np.full(len(steps), 5.0), abs=1e-6), name  # 10 m/s, dt 0.5, no hold
        assert np.diff(tr.t_s) == pytest.approx(np.full(len(steps), 0.5))
        # an arrived vehicle is frozen: its track ends inside the arrival radius
        goal = reference.mission.vehicle(name).goal_enu_m
        assert math.hypot(tr.x_m[-1] - goal[0], tr.y_m[-1] - goal[1]) <= 20.0
    assert all(r.arrived for r in (reference.ticks["a"][-1], reference.ticks["b"][-1]))


# On the multicopter plant this mirror-image pair dodges in step until the geofence, where the
# spin recovery dithers between two half turns (the yaw lags): a planner issue, not this test's.
TWO_WAY = """
name: head_on
plant: unicycle
area: {x_min_m: 0, y_min_m: -500, x_max_m: 2000, y_max_m: 500}
stations: {A: [0, 0], B: [2000, 0]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 0}
  - {name: b, start: B, goal: A, initial_heading_deg: 180}
planner: {variant: dwa}
"""


def test_head_on_vehicles_keep_their_separation():
    run = simulate(parse_mission(TWO_WAY, "head_on"))
    assert run.summary.success, run.summary.reason
    assert run.summary.min_separation_m >= 50.0


CROSSING = """
name: crossing
area: {x_min_m: 0, y_min_m: -800, x_max_m: 2000, y_max_m: 800}
stations: {A: [0, 0], B: [2000, 0]}
obstacles:
  # both timed to be on the straight line A-B when the vehicle gets there
  - {id: cart, shape: circle, center: [1000, -500], radius_m: 120,
     motion: {type: shuttle, to: [1000, 700], speed_m_s: 5}}
  - {id: box, shape: rectangle, center: [600, 240], width_m: 200, height_m: 100, rotation_deg: 20,
     motion: {type: shuttle, to: [600, -500], speed_m_s: 4}}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 0}
planner: {variant: bdwa}
"""


def test_moving_obstacles_are_dodged_with_their_true_motion_checked():
    mission = parse_mission(CROSSING, "crossing")
    run = simulate(mission)
    assert run.summary.success, run.summary.reason
    tr = run.tracks["a"]
    assert np.ptp(tr.y_m) > 50.0  # it had to leave the straight line
    assert run.summary.vehicles["a"].min_obstacle_clearance_m > 0.0


TRAP = """
name: trap
area: {x_min_m: 0, y_min_m: -600, x_max_m: 1500, y_max_m: 600}
stations: {A: [0, 0], B: [1500, 0]}
obstacles:
  - {id: cup, shape: polygon, vertices: [[500, -300], [900, -300], [900, 300], [500, 300], [500, 240],
                                         [840, 240], [840, -240], [500, -240]]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 0}
planner: {variant: dwa}
safety: {time_limit_s: 300}
"""


def test_a_trapped_local_planner_fails_safe_by_timeout_not_collision():
    run = simulate(parse_mission(TRAP, "trap"))
    s = run.summary
    assert not s.success and s.reason == "timeout"
    assert s.vehicles["a"].min_obstacle_clearance_m > 0.0
    assert run.tracks["a"].t_s[-1] == pytest.approx(300.0)


def test_variant_argument_overrides_the_mission():
    run = simulate(parse_mission(TWO_WAY, "head_on"), "bdwa")
    assert run.variant == "bdwa" and run.routes == {}


WHIRL = """
name: whirl
area: {x_min_m: 0, y_min_m: -600, x_max_m: 2000, y_max_m: 600}
stations: {A: [0, 0], B: [2000, 0]}
obstacles:
  # 60 m/s around a 300 m circle: far outside what constant-velocity prediction can foresee
  - {id: blade, shape: rectangle, center: [1000, 300], width_m: 120, height_m: 60,
     motion: {type: orbit, pivot: [1000, 0], speed_m_s: 60}}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 0}
planner: {variant: dwa}
"""


def test_the_run_stops_at_the_step_that_collides():
    run = simulate(parse_mission(WHIRL, "whirl"))
    s = run.summary
    assert s.reason == "collision" and not s.success
    tr = run.tracks["a"]
    assert tr.t_s[-1] == s.failure_t_s  # nothing flown after the violation is kept
    assert len(run.ticks["a"]) == len(tr) - 1
    blade = run.mission.world.obstacles[0]
    last = LineString([(tr.x_m[-2], tr.y_m[-2]), (tr.x_m[-1], tr.y_m[-1])])
    before = LineString([(tr.x_m[-3], tr.y_m[-3]), (tr.x_m[-2], tr.y_m[-2])])
    assert last.intersects(blade.footprint_at(tr.t_s[-1])) or last.intersects(blade.footprint_at(tr.t_s[-2]))
    assert not before.intersects(blade.footprint_at(tr.t_s[-3]))


# --- the command line ----------------------------------------------------------------------------

def test_cli_simulate_writes_summary_and_plot(tmp_path, capsys):
    from companion.cli import main
    # The small reference: the reference's own flight is scored above, without the CLI around it.
    code = main(["simulate", "missions/small_reference.yaml", "--out", str(tmp_path)])
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["success"] is True and summary["vehicles"]["a"]["arrived"] is True
    assert summary["planner_no_rollout_ticks"] == {"a": 0, "b": 0}
    assert (tmp_path / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert "SUCCESS" in out and "ratio" in out


def test_cli_simulate_failed_flight_exits_1(tmp_path):
    from companion.cli import main
    mission = tmp_path / "trap.yaml"
    mission.write_text(TRAP)
    assert main(["simulate", str(mission), "--out", str(tmp_path / "out")]) == 1
    assert (tmp_path / "out" / "summary.json").exists()


BOXED = """
area: {x_min_m: 0, y_min_m: -600, x_max_m: 1500, y_max_m: 600}
stations: {A: [0, 0], B: [1000, 0]}
obstacles:  # a closed box of four walls around B
  - {shape: rectangle, center: [850, 0], width_m: 40, height_m: 340}
  - {shape: rectangle, center: [1150, 0], width_m: 40, height_m: 340}
  - {shape: rectangle, center: [1000, 150], width_m: 340, height_m: 40}
  - {shape: rectangle, center: [1000, -150], width_m: 340, height_m: 40}
vehicles:
  - {name: a, start: A, goal: B}
"""


@pytest.mark.parametrize(("text", "needle"), [(BOXED, "no path for vehicle 'a'"),
                                               ("vehicles: [}", "YAML syntax")])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, text, needle):
    from companion.cli import main
    mission = tmp_path / "bad.yaml"
    mission.write_text(text)
    assert main(["simulate", str(mission), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_sweep_rows_vary_the_reference_as_the_paper_does():
    from companion.bench.paper_tables import table_missions
    base = load_mission("missions/paper_reference.yaml")
    t1 = table_missions("table1", base)
    assert [(m.vehicle("a").initial_heading_deg, m.vehicle("b").initial_heading_deg) for _, m in t1] == \
        [(a, a - 180.0) for a in (0.0, 18.0, 36.0, 54.0, 72.0, 90.0)]
    assert [m.vehicle("a").speed_m_s for _, m in table_missions("table2", base)] == [10.0, 20.0, 30.0]
    for label, m in table_missions("table3", base):
        (o,) = m.world.obstacles
        b = np.array(m.vehicle("a").goal_enu_m)
        assert m.vehicle("a").start_enu_m == (0.0, 0.0) and m.vehicle("b").goal_enu_m == (0.0, 0.0)
        assert math.hypot(*o.center) == pytest.approx(float(label))
        assert np.hypot(*(b - o.center)) == pytest.approx(1000.0)
        assert o.footprint.centroid.distance(Point(o.center)) < 1e-6


POCKET = """
name: pocket
area: {x_min_m: 0, y_min_m: -600, x_max_m: 1500, y_max_m: 600}
stations: {A: [0, 0], B: [700, 0]}
obstacles:
  # a corridor 56 m wide between the inflated walls: too narrow for a 30 m-radius U-turn
  - {id: cup, shape: polygon, vertices: [[500, -300], [900, -300], [900, 300], [500, 300], [500, 100],
                                         [840, 100], [840, -100], [500, -100]]}
vehicles:
  # starts deep inside the cup, facing its closed end: no cruise rollout is legal
  - {name: a, start: B, goal: A, initial_heading_deg: 0}
planner: {variant: dwa}
safety: {time_limit_s: 400}
"""


def test_a_vehicle_in_a_pocket_yaws_in_place_and_leaves():
    run = simulate(parse_mission(POCKET, "pocket"))
    s = run.summary
    assert s.success, s.reason
    recovering = [r for r in run.ticks["a"] if r.recovery_reason is not None]
    assert recovering and all(r.speed_m_s == 0.0 and r.yaw_rate_rad_s != 0.0 for r in recovering)
    assert s.planner["a"].recovery_ticks == len(recovering)
    assert s.vehicles["a"].min_obstacle_clearance_m > 0.0


def test_the_timed_variant_flies_head_on_vehicles_apart_and_paper_variants_keep_constant_speed():
    mission = parse_mission(TWO_WAY, "head_on")
    run = simulate(mission, "astar-bdwa-timed")
    assert run.variant == "astar-bdwa-timed"
    assert run.summary.success, run.summary.reason
    assert run.summary.min_separation_m >= 50.0
    paper = simulate(mission, "astar-bdwa")
    assert {r.speed_m_s for ticks in paper.ticks.values() for r in ticks if r.command is not None} == {10.0}
