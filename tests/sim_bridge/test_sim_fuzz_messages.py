"""Hostile but well-formed messages of every type never break the vehicle state machine."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import parse_mission
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.testing import GcsCodec, random_message

pytestmark = pytest.mark.timeout(120)

MISSION_YAML = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
obstacles:
  - id: mover
    shape: circle
    center: [300, 700]
    radius_m: 30
    motion: {type: orbit, pivot: [500, 700], speed_m_s: 5}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 5}
"""
# Messages a vehicle acts on, weighted in so the fuzz reaches the handlers, plus every other type.
HANDLED = [mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT,
           mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, mavlink.MAVLINK_MSG_ID_SET_MODE,
           mavlink.MAVLINK_MSG_ID_PARAM_SET, mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
           mavlink.MAVLINK_MSG_ID_MISSION_COUNT, mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT,
           mavlink.MAVLINK_MSG_ID_MISSION_ITEM, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
           mavlink.MAVLINK_MSG_ID_MISSION_REQUEST, mavlink.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
           mavlink.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, mavlink.MAVLINK_MSG_ID_MISSION_ACK,
           mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST, mavlink.MAVLINK_MSG_ID_TIMESYNC]


COMMANDS = [mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL,
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_LAND,
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_MISSION_START,
            mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_DO_REPOSITION]
ITEM_COMMANDS = [mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_LAND,
                 mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH]
PARAMS = [b"MIS_TAKEOFF_ALT", b"COM_OF_LOSS_T", b"MPC_XY_VEL_MAX", b"MPC_ACC_HOR", b"MPC_YAWRAUTO_MAX", b"SYS_HITL",
          b"NAV_ACC_RAD", b"MPC_LAND_SPEED"]


def steer(msg, rng):
    """Point many random messages at real commands, params and item types, so handlers run deep."""
    if hasattr(msg, "command") and rng.random() < 0.8:
        msg.command = rng.choice(ITEM_COMMANDS if msg.get_type().startswith("MISSION_ITEM") else COMMANDS)
        if msg.command == mavlink.MAV_CMD_DO_SET_MODE and rng.random() < 0.7:
            msg.param1, msg.param2, msg.param3 = 1.0, float(rng.choice((3, 4, 6))), float(rng.randint(0, 7))
        if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and rng.random() < 0.7:
            msg.param1 = float(rng.choice((0, 1)))
    if hasattr(msg, "param_id") and rng.random() < 0.7:
        msg.param_id = rng.choice(PARAMS).decode()
    if hasattr(msg, "frame") and rng.random() < 0.5:
        msg.frame = rng.choice((mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_FRAME_LOCAL_NED,
                                mavlink.MAV_FRAME_GLOBAL))
    if hasattr(msg, "coordinate_frame") and rng.random() < 0.7:
        msg.coordinate_frame = rng.choice((mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_NED))
        msg.type_mask = rng.choice((0x5C7, 0x9C7, 0xDF8, 0x1C7, msg.type_mask))
    if hasattr(msg, "seq") and rng.random() < 0.7:
        msg.seq = rng.randint(0, 4)
    if hasattr(msg, "count") and rng.random() < 0.7:
        msg.count = rng.choice((0, 1, 3, 5, 65535))
    return msg


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "fuzz.yaml")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1))
def test_random_messages_never_crash_a_handler_or_corrupt_the_state(mission, make_vehicle, seed):
    rng = random.Random(seed)
    gcs = GcsCodec()
    v = make_vehicle(mission)
    ids = sorted(mavlink.mavlink_map)
    for k in range(150):
        msg = steer(random_message(rng, target_system=rng.choice((0, 1, 1, 1, 7)),
                                   message_ids=HANDLED if rng.random() < 0.7 else ids), rng)
        if hasattr(msg, "target_component") and rng.random() < 0.8:
            msg.target_component = 1
        try:
            wire = gcs.wire(msg)
        except Exception:  # noqa: BLE001 - some random values cannot be packed; not the vehicle's problem
            continue
        for e in v.handle(wire, "api"):
            e.msg.pack(mavlink.MAVLink(None, 1, 1))  # everything the vehicle emits can go on the wire
        for e in v.step(0.05):
            e.msg.pack(mavlink.MAVLink(None, 1, 1))
        v.telemetry(k * 0.05)
        v.poll(k * 0.05)
    assert v.counters["handler_error"] == 0 and v.counters["step_error"] == 0, v.counters
    s = v.state
    assert all(math.isfinite(x) for x in (s.north_m, s.east_m, s.down_m, s.vn_m_s, s.ve_m_s, s.yaw_rad))
    assert s.ground_speed_m_s <= v.limits.max_speed_m_s + 1e-6 and -s.down_m <= v.limits.max_alt_m
    assert isinstance(v.mode, FlightMode)
    for name in ("COM_OF_LOSS_T", "MPC_XY_VEL_MAX", "MIS_TAKEOFF_ALT"):
        assert math.isfinite(v.param(name))
    # Still answering.
    (ack,) = [e.msg for e in v.handle(gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HEARTBEAT),
                                      "api") if e.msg.get_type() == "COMMAND_ACK"]
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
