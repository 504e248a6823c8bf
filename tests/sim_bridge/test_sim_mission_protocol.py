"""The vehicle side of the MAVLink mission protocol, and AUTO.MISSION flying, without sockets."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import local_to_geodetic
from uav_model.mission import parse_mission
from sim_bridge.vehicle.mission_protocol import MAX_ITEMS, MissionProtocol
from sim_bridge.vehicle.px4 import FlightMode

from sim_bridge.testing import GcsCodec as Gcs, send_command, step_for

pytestmark = pytest.mark.timeout(60)

MISSION_YAML = """
name: unit
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000, geofence_margin_m: 100}
stations: {A: [100, 100], B: [900, 900]}
obstacles:
  - {id: wall, shape: rectangle, center: [300, 100], width_m: 20, height_m: 100}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10}
  - {name: b, start: B, goal: A, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10}
"""
DT = 0.02


run = step_for
send = send_command

MISSION, FENCE, RALLY = (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_FENCE,
                         mavlink.MAV_MISSION_TYPE_RALLY)
REL_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "unit.yaml")


@pytest.fixture
def proto():
    return MissionProtocol(1, 1, mavlink.MAVLink(None, 1, 1), retry_timeout_s=0.25, transfer_timeout_s=5.0)


def waypoint(gcs, mission, seq, x_m, y_m, alt_m, *, hold_s=0.0, accept_m=0.0, command=mavlink.MAV_CMD_NAV_WAYPOINT,
             mission_type=MISSION, frame=REL_INT, target=1):
    lat, lon, _ = local_to_geodetic(mission.origin, x_m, y_m)
    return gcs.wire(gcs.enc.mission_item_int_encode(target, 1, seq, frame, command, 1 if seq == 0 else 0, 1,
                                                    hold_s, accept_m, 0.0, math.nan, int(round(lat * 1e7)),
                                                    int(round(lon * 1e7)), alt_m, mission_type))


def count(gcs, n, mission_type=MISSION):
    return gcs.wire(gcs.enc.mission_count_encode(1, 1, n, mission_type))


def types(replies):
    return [(r.msg.get_type(), getattr(r.msg, "seq", getattr(r.msg, "type", None))) for r in replies]


def upload(proto, gcs, items, mission_type=MISSION, wall_t=0.0):
    replies, _ = proto.handle(count(gcs, len(items), mission_type), "api", None, wall_t)
    events = []
    for item in items:
        assert types(replies) == [("MISSION_REQUEST_INT", item.seq)]
        replies, ev = proto.handle(item, "api", None, wall_t)
        events += ev
    return replies, events


# ---------------------------------------------------------------- transfers ---------------
def test_upload_then_download_gives_back_the_same_items(mission, proto, gcs):
    items = [waypoint(gcs, mission, i, 100.0 * i, 50.0, 20.0 + i) for i in range(4)]
    replies, events = upload(proto, gcs, items)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)]
    assert replies[0].msg.target_system == 245 and replies[0].msg.mission_type == MISSION
    assert [e.kind for e in events] == ["replaced"]
    replies, _ = proto.handle(gcs.wire(gcs.enc.mission_request_list_encode(1, 1, MISSION)), "api", None, 0.0)
    assert replies[0].msg.get_type() == "MISSION_COUNT" and replies[0].msg.count == 4
    for item in items:
        replies, _ = proto.handle(gcs.wire(gcs.enc.mission_request_int_encode(1, 1, item.seq, MISSION)), "api", None, 0.0)
        (got,) = [r.msg for r in replies]
        for field in ("seq", "frame", "command", "current", "autocontinue", "param1", "param2", "param3", "x", "y",
                      "z", "mission_type"):
            assert getattr(got, field) == getattr(item, field), field
        assert math.isnan(got.param4)


def test_mission_types_are_stored_separately(mission, proto, gcs):
    upload(proto, gcs, [waypoint(gcs, mission, 0, 10, 10, 10)])
    fence = [waypoint(gcs, mission, i, 10 * i, 0, 0, hold_s=3.0, command=mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                      mission_type=FENCE, frame=mavlink.MAV_FRAME_GLOBAL_INT) for i in range(3)]
    replies, events = upload(proto, gcs, fence, FENCE)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)] and events[0].mission_type == FENCE
    assert len(proto.plan(MISSION)) == 1 and len(proto.plan(FENCE)) == 3 and proto.plan(RALLY) == ()
    # A waypoint is not a fence item.
    replies, _ = upload(proto, gcs, [waypoint(gcs, mission, 0, 1, 1, 1, mission_type=FENCE)], FENCE)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_UNSUPPORTED)]
    assert len(proto.plan(FENCE)) == 3
    replies, events = proto.handle(gcs.wire(gcs.enc.mission_clear_all_encode(1, 1, FENCE)), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)]
    assert proto.plan(FENCE) == () and len(proto.plan(MISSION)) == 1
    proto.handle(gcs.wire(gcs.enc.mission_clear_all_encode(1, 1, mavlink.MAV_MISSION_TYPE_ALL)), "api", None, 0.0)
    assert proto.plan(MISSION) == ()


@pytest.mark.parametrize("command, param1, code", [
    (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, mavlink.MAV_MISSION_ACCEPTED),  # MAVSDK's geofence example
    (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 25.0, mavlink.MAV_MISSION_ACCEPTED),
    (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, -1.0, mavlink.MAV_MISSION_INVALID_PARAM1),
    (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, math.nan, mavlink.MAV_MISSION_INVALID_PARAM1),
    (mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, 2.0, mavlink.MAV_MISSION_INVALID_PARAM1),
])
def test_fence_circles_of_radius_0_are_stored_and_polygons_need_3_vertices(mission, proto, gcs, command, param1, code):
    """As PX4: it stores a radius-0 circle and refuses only polygons of fewer than 3 vertices."""
    item = waypoint(gcs, mission, 0, 10, 10, 0, hold_s=param1, command=command, mission_type=FENCE,
                    frame=mavlink.MAV_FRAME_GLOBAL_INT)
    proto.handle(count(gcs, 1, FENCE), "api", None, 0.0)
    replies, _ = proto.handle(item, "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", code)]
    assert len(proto.plan(FENCE)) == (1 if code == mavlink.MAV_MISSION_ACCEPTED else 0)


@pytest.mark.parametrize("n", [MAX_ITEMS[MISSION] + 1, 65535])
def test_absurd_counts_are_refused_with_no_space(proto, gcs, n):
    replies, _ = proto.handle(count(gcs, n), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_NO_SPACE)]
    assert not proto.upload_active


def test_out_of_order_item_ends_the_upload_with_invalid_sequence_and_keeps_the_old_plan(mission, proto, gcs):
    upload(proto, gcs, [waypoint(gcs, mission, 0, 10, 10, 10)])
    proto.handle(count(gcs, 3), "api", None, 0.0)
    replies, _ = proto.handle(waypoint(gcs, mission, 2, 0, 0, 10), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_INVALID_SEQUENCE)]
    assert not proto.upload_active and len(proto.plan(MISSION)) == 1


def test_duplicate_item_is_answered_by_asking_again(mission, proto, gcs):
    proto.handle(count(gcs, 2), "api", None, 0.0)
    proto.handle(waypoint(gcs, mission, 0, 0, 0, 10), "api", None, 0.0)
    replies, _ = proto.handle(waypoint(gcs, mission, 0, 0, 0, 10), "api", None, 0.0)
    assert types(replies) == [("MISSION_REQUEST_INT", 1)]


@pytest.mark.parametrize("kwargs, code", [
    (dict(frame=mavlink.MAV_FRAME_LOCAL_NED), mavlink.MAV_MISSION_UNSUPPORTED_FRAME),
    (dict(command=mavlink.MAV_CMD_DO_SET_SERVO), mavlink.MAV_MISSION_UNSUPPORTED),
    (dict(hold_s=math.nan), mavlink.MAV_MISSION_INVALID_PARAM1),
    (dict(alt_m=math.nan), mavlink.MAV_MISSION_INVALID_PARAM7),
])
def test_invalid_items_get_the_matching_ack(mission, proto, gcs, kwargs, code):
    proto.handle(count(gcs, 1), "api", None, 0.0)
    replies, _ = proto.handle(waypoint(gcs, mission, 0, 0, 0, kwargs.pop("alt_m", 10.0), **kwargs), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", code)]


def test_latitude_out_of_range_is_invalid_param5(proto, gcs):
    proto.handle(count(gcs, 1), "api", None, 0.0)
    bad = gcs.wire(gcs.enc.mission_item_int_encode(1, 1, 0, REL_INT, mavlink.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0,
                                                   950_000_000, 0, 10.0, MISSION))
    replies, _ = proto.handle(bad, "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_INVALID_PARAM5_X)]


def test_stalled_upload_is_re_requested_then_times_out_on_the_wall_clock(mission, proto, gcs):
    proto.handle(count(gcs, 2), "api", None, 100.0)
    assert proto.poll(100.1) == []
    assert types(proto.poll(100.26)) == [("MISSION_REQUEST_INT", 0)]  # retry after 0.25 s
    proto.handle(waypoint(gcs, mission, 0, 0, 0, 10), "api", None, 101.0)
    retries = [r for k in range(1, 60) for r in proto.poll(101.0 + 0.1 * k)]
    assert retries and all(r.msg.seq == 1 for r in retries)
    assert not proto.upload_active  # given up 5 s after the last progress
    assert proto.counters["upload_timeout"] == 1 and proto.plan(MISSION) == ()


def test_second_partner_is_denied_during_an_upload(mission, proto, gcs):
    proto.handle(count(gcs, 2), "api", None, 0.0)
    other = Gcs()
    other.enc.srcSystem = 200
    replies, _ = proto.handle(other.wire(other.enc.mission_count_encode(1, 1, 1, MISSION)), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_DENIED)]
    assert proto.upload_active


def test_download_of_missing_item_is_invalid_sequence(proto, gcs):
    replies, _ = proto.handle(gcs.wire(gcs.enc.mission_request_int_encode(1, 1, 7, MISSION)), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_INVALID_SEQUENCE)]


def test_lost_final_ack_is_resent_when_the_last_item_comes_again(mission, proto, gcs):
    items = [waypoint(gcs, mission, i, i, 0, 10) for i in range(2)]
    upload(proto, gcs, items)
    replies, _ = proto.handle(items[-1], "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)]


def test_count_zero_clears(mission, proto, gcs):
    upload(proto, gcs, [waypoint(gcs, mission, 0, 0, 0, 10)])
    replies, events = proto.handle(count(gcs, 0), "api", None, 0.0)
    assert types(replies) == [("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)] and events[0].kind == "cleared"
    assert proto.plan(MISSION) == ()


# ---------------------------------------------------------------- AUTO.MISSION ------------
@pytest.fixture
def vehicle_with_plan(make_vehicle):
    def make(mission, gcs, wps):
        v = make_vehicle(mission)
        items = [waypoint(gcs, mission, i, *wp) for i, wp in enumerate(wps)]
        v.handle(count(gcs, len(items)), "api")
        for item in items:
            v.handle(item, "api")
        assert len(v.missions.plan()) == len(items)
        return v

    return make


def test_mission_flies_waypoints_reports_progress_and_ends_in_hold(mission, gcs, vehicle_with_plan):
    wps = [(100.0, 200.0, 15.0), (200.0, 200.0, 15.0), (200.0, 150.0, 20.0)]
    v = vehicle_with_plan(mission, gcs, wps)
    assert send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    assert send(v, gcs, mavlink.MAV_CMD_MISSION_START, 0, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert v.mode is FlightMode.MISSION
    emitted = run(v, 300.0, until=lambda v: v.mode is not FlightMode.MISSION)
    assert v.mode is FlightMode.HOLD and v.mission_finished and v.collision_count == 0
    reached = [m.seq for m in emitted if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [0, 1, 2]
    currents = [m.seq for m in emitted if m.get_type() == "MISSION_CURRENT"]
    assert currents == sorted(currents) and currents[-1] == 2
    run(v, 20.0)
    assert v.position_enu_m == pytest.approx(wps[-1], abs=0.5)  # it holds at the last waypoint
    assert all(abs(m.vx) <= 1000.01 for m in v.build(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT))
    (cur,) = v.build(mavlink.MAVLINK_MSG_ID_MISSION_CURRENT)
    assert cur.mission_state == mavlink.MISSION_STATE_COMPLETE and cur.total == 3


def test_mission_ending_with_land_lands_and_disarms(mission, gcs, vehicle_with_plan):
    v = vehicle_with_plan(mission, gcs, [(100.0, 150.0, 10.0)])
    items = [waypoint(gcs, mission, 0, 100.0, 150.0, 10.0),
             waypoint(gcs, mission, 1, 150.0, 150.0, 0.0, command=mavlink.MAV_CMD_NAV_LAND)]
    v.handle(count(gcs, 2), "api")
    for item in items:
        v.handle(item, "api")
    send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    send(v, gcs, mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 4)  # what MAVSDK's start_mission sends
    emitted = run(v, 300.0, until=lambda v: not v.armed)
    assert not v.armed and v.mode is FlightMode.MISSION  # PX4 stays in MISSION, landed and disarmed
    assert [m.seq for m in emitted if m.get_type() == "MISSION_ITEM_REACHED"] == [0, 1]
    assert v.position_enu_m == pytest.approx((150.0, 150.0, 0.0), abs=1.5)


def test_set_current_jumps_and_mission_without_plan_is_denied(mission, gcs, make_vehicle, vehicle_with_plan):
    v = make_vehicle(mission)
    # ACCEPTED as PX4 acks it, but the mode does not change without a plan.
    assert send(v, gcs, mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 4).result == mavlink.MAV_RESULT_ACCEPTED
    assert v.mode is FlightMode.HOLD
    v = vehicle_with_plan(mission, gcs, [(100.0, 150.0, 10.0), (150.0, 150.0, 10.0), (150.0, 100.0, 10.0)])
    emits = v.handle(gcs.wire(gcs.enc.mission_set_current_encode(1, 1, 2)), "api")
    assert [(e.msg.get_type(), e.msg.seq) for e in emits] == [("MISSION_CURRENT", 2)]
    send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    send(v, gcs, mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 4)
    emitted = run(v, 200.0, until=lambda v: v.mission_finished)
    assert [m.seq for m in emitted if m.get_type() == "MISSION_ITEM_REACHED"] == [2]
    emits = v.handle(gcs.wire(gcs.enc.mission_set_current_encode(1, 1, 9)), "api")
    assert "STATUSTEXT" in [e.msg.get_type() for e in emits]
