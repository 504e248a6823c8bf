"""Before anything flies: planning the routes, turning them into MAVLink missions, checking read-back."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from uav_model import frames
from companion.app.flight_plan import prepare, verify_readback
from companion.errors import MissionUploadError
from uav_model.mission import MissionError, load_mission
from companion.vehicle.convert import traffic_velocity_enu
from companion.vehicle.mavsdk_items import (MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, body_setpoint,
                                            items_to_waypoints, waypoints_to_items)
from companion.vehicle.port import GeoWaypoint, VelocityYawRateSetpoint

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
BAD = ROOT / "tests" / "data" / "bad_missions"


@pytest.fixture(scope="module")
def plan(reference_mission):
    return prepare(reference_mission)


def test_uploaded_route_is_the_sparse_route_at_cruise_altitude(plan):
    for v in plan.mission.vehicles:
        route = plan.routes[v.name]
        wps = plan.waypoints(v)
        assert len(wps) == route.nodes_sparse < route.nodes_raw
        for w, (x, y) in zip(wps, route.sparse_enu_m):
            back = frames.geodetic_to_local(plan.mission.origin, w.lat_deg, w.lon_deg)
            assert math.hypot(back[0] - x, back[1] - y) < 0.01
            assert w.alt_rel_m == v.cruise_alt_m
        assert wps[0] == GeoWaypoint(*frames.local_to_geodetic(plan.mission.origin, *v.start_enu_m)[:2],
                                     v.cruise_alt_m)


@pytest.mark.parametrize("variant, expected", [("astar-bdwa-nosparse", "raw"), ("bdwa", 2), ("dwa", 2)])
def test_every_variant_uploads_the_nodes_its_planner_follows(variant, expected, reference_mission):
    plan = prepare(reference_mission, variant)
    for v in plan.mission.vehicles:
        n = len(plan.waypoints(v))
        assert n == (plan.routes[v.name].nodes_raw if expected == "raw" else expected)


def test_mission_items_round_trip_as_mission_item_int(plan):
    v = plan.mission.vehicles[0]
    wps = plan.waypoints(v)
    items = waypoints_to_items(wps, 30.0)
    assert [i.seq for i in items] == list(range(len(wps)))
    assert all(i.command == MAV_CMD_NAV_WAYPOINT and i.frame == MAV_FRAME_GLOBAL_RELATIVE_ALT_INT for i in items)
    assert [i.current for i in items] == [1] + [0] * (len(items) - 1)
    assert all(isinstance(i.x, int) and isinstance(i.y, int) for i in items)
    verify_readback(v.name, wps, items_to_waypoints(items))  # 1e-7 degree rounding is accepted


def test_a_changed_or_short_read_back_is_refused(plan):
    v = plan.mission.vehicles[0]
    wps = plan.waypoints(v)
    with pytest.raises(MissionUploadError, match="read back 1 waypoints"):
        verify_readback(v.name, wps, wps[:1])
    moved = list(wps)
    moved[1] = GeoWaypoint(wps[1].lat_deg + 1e-5, wps[1].lon_deg, wps[1].alt_rel_m)
    with pytest.raises(MissionUploadError, match="waypoint 1"):
        verify_readback(v.name, wps, moved)


def test_unreachable_goal_is_bad_input_naming_the_vehicle_goal_and_line():
    mission = load_mission(BAD / "unreachable_goal.yaml")
    with pytest.raises(MissionError) as info:
        prepare(mission)
    err = info.value
    assert err.field_path.startswith("vehicles[") and err.field_path.endswith("].goal")
    assert err.line is not None
    text = str(err)
    assert "\n" not in text and text.startswith(str(BAD / "unreachable_goal.yaml"))


def test_body_setpoint_flips_the_yaw_rate_sign_for_px4():
    left = body_setpoint(VelocityYawRateSetpoint(forward_m_s=10.0, yaw_rate_enu_rad_s=math.radians(10.0)))
    assert left.forward_m_s == 10.0 and left.right_m_s == 0.0 and left.down_m_s == 0.0
    assert left.yawspeed_deg_s == pytest.approx(-10.0)  # CCW in ENU is a negative (CW-positive) yawspeed
    climb = body_setpoint(VelocityYawRateSetpoint(0.0, 0.0, climb_m_s=2.0))
    assert climb.down_m_s == -2.0


@pytest.mark.parametrize("course_deg, vx, vy", [(0.0, 0.0, 4.0), (90.0, 4.0, 0.0), (180.0, 0.0, -4.0),
                                                 (270.0, -4.0, 0.0), (45.0, 2.828427, 2.828427)])
def test_adsb_course_becomes_an_enu_velocity(course_deg, vx, vy):
    got = traffic_velocity_enu(course_deg, 4.0)
    assert got == pytest.approx((vx, vy), abs=1e-6)
