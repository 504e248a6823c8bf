"""The stub's vehicle state machine, driven without sockets or an event loop.

Messages are really encoded and decoded with pymavlink (a GCS codec packs them, a parser reads
them back), so the vehicle sees exactly what it sees on a link.
"""

from __future__ import annotations

import math
import struct

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import enu_heading_to_ned_yaw, geodetic_to_local, local_to_geodetic
from uav_model.mission import parse_mission
from sim_bridge.vehicle.px4 import FlightMode, Px4AutoSubMode, Px4MainMode, decode_custom_mode, encode_custom_mode
from sim_bridge.vehicle.streams import API_PROFILE
from sim_bridge.testing import GcsCodec, ack_of, send_command, step_for
from sim_bridge.vehicle import ADSB_ICAO_BASE, LandedState

pytestmark = pytest.mark.timeout(60)

# The state machine's tests assert the unicycle's exact kinematics; the multicopter plant's are
# in tests/model/test_plant_fit.py and test_sim_multicopter.py.
MISSION_YAML = """
name: unit
plant: unicycle
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000, geofence_margin_m: 100}
stations: {A: [100, 100], B: [900, 900]}
obstacles:
  - {id: wall, shape: rectangle, center: [300, 100], width_m: 20, height_m: 100}
  - id: mover
    shape: circle
    center: [300, 700]
    radius_m: 30
    motion: {type: shuttle, to: [700, 700], speed_m_s: 4}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10,
     initial_heading_deg: 45, battery_pct: 100}
  - {name: b, start: B, goal: A, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10,
     initial_heading_deg: -135, battery_pct: 35}
"""

DT = 0.02
GCS_SYS, GCS_COMP = 245, 190


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "unit.yaml")


Gcs = GcsCodec
run = step_for
send = send_command


@pytest.fixture
def vehicle(mission, make_vehicle):
    return make_vehicle(mission)


def takeoff(v, gcs):
    assert send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    nan = math.nan
    ack = send(v, gcs, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 30, until=lambda v: v.mode is FlightMode.HOLD)
    assert v.mode is FlightMode.HOLD and v.in_air


def int32_param(value: int) -> float:
    """An INT32 parameter value as PX4 puts it on the wire (the bytes, read as a float)."""
    return struct.unpack("<f", struct.pack("<i", value))[0]


def setpoint_body(gcs, fwd, right, down, yaw_rate):
    mask = 0x5C7  # what MAVSDK set_velocity_body sends: velocity + yaw rate, BODY_NED
    return gcs.wire(gcs.enc.set_position_target_local_ned_encode(
        0, 1, 1, mavlink.MAV_FRAME_BODY_NED, mask, 0, 0, 0, fwd, right, down, 0, 0, 0, 0, yaw_rate))


def setpoint_ned_yaw(gcs, vn, ve, vd, yaw):
    mask = 0x9C7  # what MAVSDK set_velocity_ned sends: velocity + yaw ANGLE, LOCAL_NED
    return gcs.wire(gcs.enc.set_position_target_local_ned_encode(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, 0, 0, 0, vn, ve, vd, 0, 0, 0, yaw, 0))


def fly_offboard(v, gcs, make_setpoint, seconds, every_s=0.1, check=None):
    """Stream a setpoint every ``every_s`` sim seconds while stepping; ``check(v)`` each step."""
    per = int(round(every_s / DT))
    out = []
    for k in range(int(round(seconds / DT))):
        if k % per == 0:
            v.handle(make_setpoint(), "api")
        out += [e.msg for e in v.step(DT)]
        if check is not None:
            check(v)
    return out


def enter_offboard(v, gcs, make_setpoint):
    v.handle(make_setpoint(), "api")
    ack = send(v, gcs, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Px4MainMode.OFFBOARD, 0)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert v.mode is FlightMode.OFFBOARD


# ---------------------------------------------------------------- modes and heartbeat -----
def test_px4_custom_modes_match_pymavlink_and_px4_layout():
    assert FlightMode.OFFBOARD.custom_mode == mavutil.PX4_CUSTOM_MAIN_MODE_OFFBOARD << 16
    assert FlightMode.HOLD.custom_mode == (4 << 16) | (mavutil.PX4_CUSTOM_SUB_MODE_AUTO_LOITER << 24)
    assert FlightMode.MISSION.custom_mode == (4 << 16) | (mavutil.PX4_CUSTOM_SUB_MODE_AUTO_MISSION << 24)
    assert FlightMode.TAKEOFF.value == (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF)
    for mode in FlightMode:
        if mode is not FlightMode.ORBIT:  # PX4 enters orbit by DO_ORBIT, not by a mode switch
            assert FlightMode.from_px4(*decode_custom_mode(mode.custom_mode)) is mode
    assert FlightMode.ORBIT.custom_mode == (3 << 16) | (1 << 24)  # POSCTL, PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT
    assert decode_custom_mode(encode_custom_mode(4, 6)) == (4, 6)
    assert FlightMode.from_px4(Px4MainMode.MANUAL, 0) is None
    assert FlightMode.from_px4(Px4MainMode.AUTO, 99) is None


def test_vehicle_boots_landed_disarmed_at_its_station_with_its_heading(mission, vehicle):
    spec = mission.vehicles[0]
    assert vehicle.position_enu_m == (spec.start_enu_m[0], spec.start_enu_m[1], 0.0)
    assert vehicle.state.yaw_rad == pytest.approx(enu_heading_to_ned_yaw(math.radians(45.0)))
    assert not vehicle.armed and vehicle.landed_state is LandedState.ON_GROUND
    (hb,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    assert decode_custom_mode(hb.custom_mode) == (Px4MainMode.AUTO, Px4AutoSubMode.LOITER)


def test_telemetry_is_stamped_with_sim_time_and_consistent(mission, vehicle):
    t_ms = int(vehicle.sim_time_s * 1000)
    run(vehicle, 1.0)
    (lp,) = vehicle.build(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
    (gp,) = vehicle.build(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    (home,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HOME_POSITION)
    assert lp.time_boot_ms == gp.time_boot_ms == pytest.approx(t_ms + 1000, abs=1)
    x, y, _ = geodetic_to_local(mission.origin, gp.lat * 1e-7, gp.lon * 1e-7)
    assert (y, x) == pytest.approx((lp.x, lp.y), abs=0.05)  # the same point in both frames
    assert (home.x, home.y, home.z) == (lp.x, lp.y, 0.0)
    assert gp.alt == pytest.approx(mission.origin.alt_m * 1000, abs=1)
    (sys_status,) = vehicle.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS)
    wanted = 0x1 | 0x2 | 0x4 | 0x20 | 0x10000000
    for field in ("onboard_control_sensors_present", "onboard_control_sensors_enabled", "onboard_control_sensors_health"):
        assert getattr(sys_status, field) & wanted == wanted
    (gps,) = vehicle.build(mavlink.MAVLINK_MSG_ID_GPS_RAW_INT)
    assert gps.fix_type == mavlink.GPS_FIX_TYPE_3D_FIX and gps.satellites_visible >= 6


# ---------------------------------------------------------------- commands ----------------
def test_command_ack_goes_to_the_sender_and_unknown_commands_are_unsupported(vehicle, gcs):
    ack = send(vehicle, gcs, mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    assert (ack.target_system, ack.target_component) == (GCS_SYS, GCS_COMP)


@pytest.mark.parametrize("command, params", [
    (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (math.nan,)),
    (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (2.0,)),
    (mavlink.MAV_CMD_DO_SET_MODE, (math.nan, 4, 3)),
    (mavlink.MAV_CMD_DO_SET_MODE, (1, Px4MainMode.MANUAL, 0)),
    (mavlink.MAV_CMD_DO_SET_MODE, (0, Px4MainMode.AUTO, Px4AutoSubMode.LOITER)),  # no custom-mode flag
    (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (mavlink.MAVLINK_MSG_ID_ATTITUDE, math.nan)),
    (mavlink.MAV_CMD_REQUEST_MESSAGE, (math.nan,)),
    (mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 10.0)),  # 10 m AMSL is below home (488 m)
    (mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, (5,)),  # no such item
])
def test_invalid_commands_are_denied(vehicle, gcs, command, params):
    assert send(vehicle, gcs, command, *params).result == mavlink.MAV_RESULT_DENIED
    assert not vehicle.armed and vehicle.mode is FlightMode.HOLD


def test_request_message_autopilot_version_advertises_mission_int_and_mavlink2(vehicle, gcs):
    emits = vehicle.handle(gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION), "api")
    assert ack_of(emits, mavlink.MAV_CMD_REQUEST_MESSAGE).result == mavlink.MAV_RESULT_ACCEPTED
    (ver,) = [e.msg for e in emits if e.msg.get_type() == "AUTOPILOT_VERSION"]
    for cap in (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT, mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2,
                mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
                mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED):
        assert ver.capabilities & cap
    emits = vehicle.handle(gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION), "api")
    assert [e.msg.get_type() for e in emits] == ["COMMAND_ACK", "HOME_POSITION"]
    assert all(e.link == "api" for e in emits)  # answered on the link it came from


def test_set_message_interval_is_per_link_and_in_sim_time(vehicle, gcs):
    vehicle.add_link("gcs", API_PROFILE)
    att = mavlink.MAVLINK_MSG_ID_ATTITUDE
    assert send(vehicle, gcs, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, att, 200_000).result == mavlink.MAV_RESULT_ACCEPTED
    assert vehicle.link_interval_s("api", att) == pytest.approx(0.2)
    assert vehicle.link_interval_s("gcs", att) == pytest.approx(1 / API_PROFILE.rates_hz[att])
    assert send(vehicle, gcs, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, att, -1).result == mavlink.MAV_RESULT_ACCEPTED
    assert vehicle.link_interval_s("api", att) is None
    assert send(vehicle, gcs, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, att, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert vehicle.link_interval_s("api", att) == pytest.approx(1 / API_PROFILE.rates_hz[att])
    assert send(vehicle, gcs, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000).result == mavlink.MAV_RESULT_UNSUPPORTED


# ---------------------------------------------------------------- arming and flying -------
def test_arm_takeoff_to_mis_takeoff_alt_then_hold(vehicle, gcs):
    assert send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    (hb,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == mavlink.MAV_STATE_ACTIVE
    nan = math.nan
    emits = vehicle.handle(gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan), "api")
    assert ack_of(emits, mavlink.MAV_CMD_NAV_TAKEOFF).result == mavlink.MAV_RESULT_ACCEPTED
    # As PX4: no extra heartbeat with the ACK; the next 1 Hz one shows the mode.
    assert not [e for e in emits if e.msg.get_type() == "HEARTBEAT"]
    (hb,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    assert decode_custom_mode(hb.custom_mode) == (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF)
    assert "Using default takeoff altitude: 2.5 m" in [m.text for m in (e.msg for e in emits)
                                                       if m.get_type() == "STATUSTEXT"]
    run(vehicle, 2.0)
    # PX4's land detector says TAKEOFF while the motors still spool up on the ground.
    assert vehicle.landed_state is LandedState.TAKEOFF and vehicle.position_enu_m[2] == 0.0
    run(vehicle, 3.0)
    assert -vehicle.state.vd_m_s <= vehicle.param("MPC_TKO_SPEED") + 1e-9
    run(vehicle, 30, until=lambda v: v.mode is FlightMode.HOLD)
    assert vehicle.mode is FlightMode.HOLD and vehicle.landed_state is LandedState.IN_AIR
    assert vehicle.position_enu_m[2] == pytest.approx(vehicle.param("MIS_TAKEOFF_ALT"), abs=0.3)
    x0, y0, z0 = vehicle.position_enu_m
    run(vehicle, 20)  # HOLD keeps the position
    assert vehicle.position_enu_m == pytest.approx((x0, y0, vehicle.param("MIS_TAKEOFF_ALT")), abs=0.3)


def test_takeoff_altitude_param7_is_amsl_in_command_long(mission, vehicle, gcs):
    send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    nan = math.nan
    ack = send(vehicle, gcs, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, mission.origin.alt_m + 6.0)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    run(vehicle, 30, until=lambda v: v.mode is FlightMode.HOLD)
    assert vehicle.position_enu_m[2] == pytest.approx(6.0, abs=0.3)


def test_arming_rules(vehicle, gcs):
    # Refused in LAND, and disarming in flight is refused unless forced.
    assert send(vehicle, gcs, mavlink.MAV_CMD_NAV_LAND).result == mavlink.MAV_RESULT_ACCEPTED
    assert send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_DENIED
    send(vehicle, gcs, mavlink.MAV_CMD_DO_SET_MODE, 1, Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
    takeoff(vehicle, gcs)
    result = send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0).result
    assert result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED and vehicle.armed  # "Disarming denied: not landed"
    assert send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED  # idempotent
    # OFFBOARD needs a setpoint stream first. PX4 still ACKs the DO_SET_MODE ACCEPTED and only
    # says "not available" in a STATUSTEXT: the heartbeat tells the truth.
    emits = vehicle.handle(gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, Px4MainMode.OFFBOARD, 0), "api")
    assert ack_of(emits, mavlink.MAV_CMD_DO_SET_MODE).result == mavlink.MAV_RESULT_ACCEPTED
    texts = [e.msg.text for e in emits if e.msg.get_type() == "STATUSTEXT"]
    assert texts == ["Switching to Offboard is currently not available"]
    assert vehicle.mode is FlightMode.HOLD


def test_weak_battery_refuses_to_arm(mission, gcs, make_vehicle):
    v = make_vehicle(mission, 1)
    assert v.battery_pct == 35.0
    param = gcs.wire(gcs.enc.param_set_encode(2, 1, b"BAT_CRIT_THR", 0.40, mavlink.MAV_PARAM_TYPE_REAL32))
    v.handle(param, "api")
    (sys_status,) = v.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS)
    assert not sys_status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=2).result == mavlink.MAV_RESULT_DENIED


def test_offboard_body_velocity_and_yaw_rate_follow_the_unicycle_within_limits(vehicle, gcs):
    takeoff(vehicle, gcs)
    lim = vehicle.limits

    def within_limits(v):
        assert v.state.ground_speed_m_s <= lim.max_speed_m_s + 1e-9
        assert abs(v.state.yawspeed_rad_s) <= lim.max_yaw_rate_rad_s + 1e-12

    enter_offboard(vehicle, gcs, lambda: setpoint_body(gcs, 8.0, 0.0, 0.0, 0.2))
    yaw0 = vehicle.state.yaw_rad
    fly_offboard(vehicle, gcs, lambda: setpoint_body(gcs, 8.0, 0.0, 0.0, 0.2), 10.0, check=within_limits)
    assert vehicle.mode is FlightMode.OFFBOARD
    assert vehicle.state.ground_speed_m_s == pytest.approx(8.0, abs=1e-6)
    assert math.remainder(vehicle.state.yaw_rad - yaw0, 2 * math.pi) == pytest.approx(0.2 * 10.0, abs=0.05)
    # Heading of travel is the body heading (forward flight).
    s = vehicle.state
    assert math.atan2(s.ve_m_s, s.vn_m_s) == pytest.approx(s.yaw_rad, abs=1e-6)
    # Beyond the limits the vehicle obeys its own: v <= speed, |yawspeed| <= v/r.
    fly_offboard(vehicle, gcs, lambda: setpoint_body(gcs, 50.0, 0.0, 0.0, 2.0), 5.0, check=within_limits)
    assert vehicle.state.ground_speed_m_s == pytest.approx(lim.max_speed_m_s)
    assert abs(vehicle.state.yawspeed_rad_s) == pytest.approx(10.0 / 30.0)


def test_offboard_ned_velocity_with_yaw_angle_turns_within_the_rate_limit(vehicle, gcs):
    takeoff(vehicle, gcs)
    make = lambda: setpoint_ned_yaw(gcs, 0.0, 5.0, 0.0, math.pi / 2)  # east, facing east  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    yaw0 = vehicle.state.yaw_rad  # 45 deg ENU heading = 45 deg NED
    rates = []
    fly_offboard(vehicle, gcs, make, 10.0, check=lambda v: rates.append(abs(v.state.yawspeed_rad_s)))
    assert max(rates) <= 10.0 / 30.0 + 1e-12
    assert vehicle.state.yaw_rad == pytest.approx(math.pi / 2, abs=1e-6)
    assert (vehicle.state.vn_m_s, vehicle.state.ve_m_s) == pytest.approx((0.0, 5.0), abs=1e-6)
    assert abs(yaw0 - math.pi / 2) / (10.0 / 30.0) < 10.0  # it took a real, rate-limited turn


def test_acceleration_is_limited(vehicle, gcs):
    takeoff(vehicle, gcs)
    make = lambda: setpoint_ned_yaw(gcs, 10.0, 0.0, 0.0, math.nan)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    speeds = []
    fly_offboard(vehicle, gcs, make, 3.0, check=lambda v: speeds.append(v.state.ground_speed_m_s))
    steps = [b - a for a, b in zip(speeds, speeds[1:])]
    assert max(steps) <= vehicle.limits.max_accel_m_s2 * DT + 1e-9
    assert speeds[-1] == pytest.approx(10.0)


def test_offboard_loss_fails_safe_to_hold_within_timeout_plus_one_tick(vehicle, gcs):
    vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"COM_OBL_RC_ACT", int32_param(5), 6)), "api")
    takeoff(vehicle, gcs)
    make = lambda: setpoint_body(gcs, 5.0, 0.0, 0.0, 0.0)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    fly_offboard(vehicle, gcs, make, 3.0)
    last_setpoint_t = vehicle.setpoint.received_t_s
    emits = run(vehicle, 5.0, until=lambda v: v.mode is not FlightMode.OFFBOARD)
    assert vehicle.mode is FlightMode.HOLD
    timeout = vehicle.param("COM_OF_LOSS_T")
    assert timeout < vehicle.sim_time_s - last_setpoint_t <= timeout + DT + 1e-9
    assert [(x.last_setpoint_t_s, x.failsafe_t_s) for x in vehicle.offboard_losses] == [(last_setpoint_t, vehicle.sim_time_s)]
    assert [(m.severity, m.text) for m in emits if m.get_type() == "STATUSTEXT"] == [
        (mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated")]
    (hb,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    assert decode_custom_mode(hb.custom_mode)[1] == Px4AutoSubMode.LOITER and hb.system_status == mavlink.MAV_STATE_CRITICAL
    # HOLD brakes and stays: no drift after the failsafe.
    run(vehicle, 5.0)
    p = vehicle.position_enu_m
    run(vehicle, 10.0)
    assert vehicle.position_enu_m == pytest.approx(p, abs=0.05)


def test_offboard_loss_timeout_follows_the_param(vehicle, gcs):
    vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"COM_OF_LOSS_T", 0.5, mavlink.MAV_PARAM_TYPE_REAL32)), "api")
    takeoff(vehicle, gcs)
    make = lambda: setpoint_body(gcs, 0.0, 0.0, 0.0, 0.0)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    last = vehicle.setpoint.received_t_s
    run(vehicle, 3.0, until=lambda v: v.mode is not FlightMode.OFFBOARD)
    assert 0.5 < vehicle.sim_time_s - last <= 0.5 + DT + 1e-9


def test_invalid_setpoints_are_ignored_and_do_not_feed_the_stream(vehicle, gcs):
    bad = [
        gcs.wire(gcs.enc.set_position_target_local_ned_encode(0, 1, 1, mavlink.MAV_FRAME_BODY_NED, 0x5C7,
                                                              0, 0, 0, math.nan, 0, 0, 0, 0, 0, 0, 0)),
        gcs.wire(gcs.enc.set_position_target_local_ned_encode(0, 1, 1, mavlink.MAV_FRAME_GLOBAL, 0x5C7,
                                                              0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0)),
        gcs.wire(gcs.enc.set_position_target_local_ned_encode(0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0xFFF,
                                                              0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0)),
        gcs.wire(gcs.enc.set_position_target_local_ned_encode(0, 7, 1, mavlink.MAV_FRAME_LOCAL_NED, 0x5C7,
                                                              0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0)),  # other system
    ]
    for msg in bad:
        assert vehicle.handle(msg, "api") == []
    assert vehicle.setpoint is None
    assert vehicle.counters["invalid_setpoint"] == 3 and vehicle.counters["wrong_target"] == 1


def test_land_descends_then_disarms_after_com_disarm_land(vehicle, gcs):
    takeoff(vehicle, gcs)
    x0, y0, _ = vehicle.position_enu_m
    assert send(vehicle, gcs, mavlink.MAV_CMD_NAV_LAND).result == mavlink.MAV_RESULT_ACCEPTED
    run(vehicle, 2.0)
    assert vehicle.landed_state is LandedState.LANDING
    emitted = run(vehicle, 60.0, until=lambda v: v.landed_state is LandedState.ON_GROUND)
    assert not vehicle.in_air and vehicle.armed and vehicle.mode is FlightMode.LAND
    assert "Landing detected" in [m.text for m in emitted if m.get_type() == "STATUSTEXT"]
    t_land = vehicle.sim_time_s
    emitted = run(vehicle, 5.0, until=lambda v: not v.armed)
    assert not vehicle.armed and "Disarmed by landing" in [m.text for m in emitted if m.get_type() == "STATUSTEXT"]
    assert vehicle.sim_time_s - t_land == pytest.approx(vehicle.param("COM_DISARM_LAND"), abs=DT + 1e-9)
    assert vehicle.position_enu_m == pytest.approx((x0, y0, 0.0), abs=0.3)
    # As PX4: back to the mode before the landing, so the next flight can arm.
    assert vehicle.mode is FlightMode.HOLD
    assert send(vehicle, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED


def test_rtl_returns_home_and_lands(mission, vehicle, gcs):
    takeoff(vehicle, gcs)
    make = lambda: setpoint_ned_yaw(gcs, 10.0, 0.0, 0.0, 0.0)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    fly_offboard(vehicle, gcs, make, 15.0)
    assert send(vehicle, gcs, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == mavlink.MAV_RESULT_ACCEPTED
    run(vehicle, 200.0, until=lambda v: not v.armed)
    hx, hy = mission.vehicles[0].start_enu_m
    assert vehicle.mode is FlightMode.OFFBOARD and not vehicle.armed  # back to the mode before RTL
    assert vehicle.position_enu_m == pytest.approx((hx, hy, 0.0), abs=1.0)


# ---------------------------------------------------------------- params ------------------
def test_params_set_read_list_and_nan_rejected(vehicle, gcs):
    emits = vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 25.0, 9)), "api")
    (pv,) = [e.msg for e in emits if e.msg.get_type() == "PARAM_VALUE"]
    assert (pv.param_id, pv.param_value) == ("MIS_TAKEOFF_ALT", 25.0)
    emits = vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", math.nan, 9)), "api")
    (pv,) = [e.msg for e in emits if e.msg.get_type() == "PARAM_VALUE"]
    assert pv.param_value == 25.0 and vehicle.param("MIS_TAKEOFF_ALT") == 25.0  # unchanged, and said so
    emits = vehicle.handle(gcs.wire(gcs.enc.param_request_read_encode(1, 1, b"COM_OF_LOSS_T", -1)), "api")
    assert [(e.msg.param_id, e.msg.param_value) for e in emits] == [("COM_OF_LOSS_T", 1.0)]
    emits = vehicle.handle(gcs.wire(gcs.enc.param_request_list_encode(1, 1)), "api")
    names = [e.msg.param_id for e in emits]
    assert {"MIS_TAKEOFF_ALT", "COM_OF_LOSS_T", "MPC_XY_VEL_MAX", "SYS_HITL"} <= set(names)
    assert [e.msg.param_index for e in emits] == list(range(len(names)))
    assert all(e.msg.param_count == len(names) for e in emits)
    assert vehicle.handle(gcs.wire(gcs.enc.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1)), "api") == []


def test_int_params_are_bytewise_as_px4(vehicle, gcs):
    emits = vehicle.handle(gcs.wire(gcs.enc.param_request_read_encode(1, 1, b"MAV_SYS_ID", -1)), "api")
    (pv,) = [e.msg for e in emits]
    assert pv.param_type == mavlink.MAV_PARAM_TYPE_INT32
    import struct
    assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == vehicle.system_id


def test_speed_param_changes_the_limit(vehicle, gcs):
    vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"MPC_XY_VEL_MAX", 4.0, 9)), "api")
    takeoff(vehicle, gcs)
    make = lambda: setpoint_body(gcs, 10.0, 0.0, 0.0, 0.0)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    fly_offboard(vehicle, gcs, make, 5.0)
    assert vehicle.state.ground_speed_m_s == pytest.approx(4.0)


# ---------------------------------------------------------------- truth, battery, ADS-B ---
def test_collision_with_true_obstacle_is_detected_once_and_announced(vehicle, gcs):
    takeoff(vehicle, gcs)  # at (100, 100); the wall spans x 290..310, y 50..150
    make = lambda: setpoint_ned_yaw(gcs, 0.0, 10.0, 0.0, math.pi / 2)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    emits = fly_offboard(vehicle, gcs, make, 30.0)
    assert vehicle.collision_count == 1
    (event,) = vehicle.collisions
    assert event.obstacle_id == "wall" and 289.0 <= event.x_m <= 291.0
    texts = [m for m in emits if m.get_type() == "STATUSTEXT" and "COLLISION" in m.text]
    assert len(texts) == 1 and texts[0].severity == mavlink.MAV_SEVERITY_CRITICAL


def test_battery_drains_in_flight_only_and_reports_it(vehicle, gcs):
    run(vehicle, 50.0)
    assert vehicle.battery_pct == 100.0  # disarmed: no drain
    takeoff(vehicle, gcs)
    p0, t0 = vehicle.battery_pct, vehicle.sim_time_s
    run(vehicle, 100.0)
    hover = vehicle.energy.hover_pct_s  # the model's own rate is the expectation
    assert p0 - vehicle.battery_pct == pytest.approx(hover * (vehicle.sim_time_s - t0), rel=0.05)
    (bat,) = vehicle.build(mavlink.MAVLINK_MSG_ID_BATTERY_STATUS)
    assert bat.battery_remaining == round(vehicle.battery_pct)
    assert bat.current_battery > 0 and bat.voltages[0] > 14000


def test_adsb_reports_each_moving_obstacle_where_it_truly_is(mission, vehicle):
    run(vehicle, 10.0 - vehicle.sim_time_s)
    msgs = vehicle.build(mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE)
    mover_index = [o.id for o in mission.world.obstacles].index("mover")
    (adsb,) = msgs  # the static wall is not reported
    mover = mission.world.obstacles[mover_index]
    assert adsb.ICAO_address == ADSB_ICAO_BASE + mover_index and adsb.callsign == "mover"
    x, y, _ = geodetic_to_local(mission.origin, adsb.lat * 1e-7, adsb.lon * 1e-7)
    assert (x, y) == pytest.approx(mover.center_at(10.0), abs=0.05)
    assert adsb.heading == 9000 and adsb.hor_velocity == 400  # due east at 4 m/s
    assert adsb.flags & mavlink.ADSB_FLAGS_VALID_COORDS and adsb.flags & mavlink.ADSB_FLAGS_VALID_VELOCITY


def test_garbage_never_raises(vehicle, gcs):
    class Weird:
        def get_type(self):
            return "COMMAND_LONG"

    assert vehicle.handle(Weird(), "api") == []
    assert vehicle.counters["handler_error"] == 1


def test_global_position_round_trips_through_the_frames_module(mission):
    lat, lon, _ = local_to_geodetic(mission.origin, 123.0, -45.0)
    assert geodetic_to_local(mission.origin, lat, lon)[:2] == pytest.approx((123.0, -45.0), abs=1e-6)
