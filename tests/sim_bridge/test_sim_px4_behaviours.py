"""PX4 behaviours a client can see that the MAVSDK examples and PX4's own logs rely on.

Driven without sockets (the vehicle's messages really pass through a pymavlink codec): the
simulated battery, STATUSTEXT's wire form, DO_ORBIT, the position + velocity setpoint, and the
parameters behind issue 11 with PX4's names, types and defaults.
"""

from __future__ import annotations

import math
import struct
from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import local_to_geodetic, wrap_pi
from uav_model.mission import parse_mission
from uav_model.plant import Plant
from sim_bridge.vehicle.px4 import FlightMode, ParamType, Px4MainMode, Px4PosctlSubMode, decode_custom_mode
from sim_bridge.testing import send_command, step_for

pytestmark = pytest.mark.timeout(60)

MISSION_YAML = """
name: px4-behaviours
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10}
"""

# Read from PX4 SIH at boot (../shared/px4-sih/characterisation/px4_sih_1x.log) with their wire types.
PX4_DEFAULTS = {
    "COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0, "COM_RCL_EXCEPT": 0, "NAV_RCL_ACT": 2, "NAV_DLL_ACT": 0,
    "COM_RC_IN_MODE": 1, "MIS_TAKEOFF_ALT": 2.5, "MPC_ACC_HOR_MAX": 5.0, "MC_YAWRATE_MAX": 200.0,
    "COM_DISARM_LAND": 2.0, "COM_DISARM_PRFLT": 10.0, "COM_FAIL_ACT_T": 5.0, "MPC_TKO_SPEED": 1.5,
    "NAV_ACC_RAD": 2.0, "COM_DL_LOSS_T": 10, "MPC_LAND_SPEED": 0.7, "SIM_BAT_DRAIN": 60.0,
    "SIM_BAT_MIN_PCT": 50.0, "COM_SPOOLUP_TIME": 1.0, "MAV_SYS_ID": 1, "GF_ACTION": 2,
    "MPC_XY_VEL_MAX": 12.0, "MPC_XY_CRUISE": 5.0, "MPC_ACC_HOR": 3.0, "MPC_YAWRAUTO_MAX": 60.0,
}
# Tuned to the mission while the plant is the paper's ideal one (the unicycle); PX4's on the multicopter.
MISSION_TUNED = {"MPC_XY_VEL_MAX": 10.0, "MPC_XY_CRUISE": 10.0, "MPC_ACC_HOR": 8.0,
                 "MPC_YAWRAUTO_MAX": math.degrees(10.0 / 30.0)}
INT_PARAMS = {"COM_OBL_RC_ACT", "COM_RCL_EXCEPT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_RC_IN_MODE", "COM_DL_LOSS_T",
              "MAV_SYS_ID", "GF_ACTION"}


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "px4.yaml")


@pytest.fixture
def vehicle(mission, make_vehicle):
    return make_vehicle(mission)


def send(v, gcs, command, *params):
    return send_command(v, gcs, command, *params).result


def airborne(v, gcs, alt_m=10.0):
    v.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", alt_m, ParamType.REAL32)), "api")
    assert send(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    nan = math.nan
    assert send(v, gcs, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan) == mavlink.MAV_RESULT_ACCEPTED
    step_for(v, 60.0, until=lambda v: v.mode is FlightMode.HOLD and v.in_air)
    step_for(v, 3.0)
    assert v.in_air and v.position_enu_m[2] == pytest.approx(alt_m, abs=0.5)


# ---------------------------------------------------------------- battery, STATUSTEXT -----
def test_without_a_mission_charge_the_battery_is_px4_sitls_simulated_one(vehicle, gcs):
    assert vehicle.spec.battery_pct is None and vehicle.battery_pct == 100.0
    step_for(vehicle, 30.0)
    assert vehicle.battery_pct == 100.0  # disarmed: full
    airborne(vehicle, gcs)
    step_for(vehicle, 5.0)
    assert 50.0 < vehicle.battery_pct < 100.0
    step_for(vehicle, 60.0)
    assert vehicle.battery_pct == 50.0  # SIM_BAT_MIN_PCT after SIM_BAT_DRAIN / 2 armed
    (status,) = vehicle.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS)
    assert status.battery_remaining == 50


def test_sys_status_shows_px4s_boot_no_sensors_then_no_gps_then_healthy(mission, make_vehicle):
    v = make_vehicle(mission, booted=False)
    seen = []
    for _ in range(60):
        (status,) = v.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS)
        seen.append((v.sim_time_s, status.onboard_control_sensors_present, status.onboard_control_sensors_health))
        step_for(v, 0.1)
    gps, prearm = mavlink.MAV_SYS_STATUS_SENSOR_GPS, mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert all(present == 0 for t, present, _ in seen if t < 2.2)
    assert all(present and not present & gps and not health & prearm for t, present, health in seen if 2.3 < t < 4.1)
    assert all(present & gps and health & prearm for t, present, health in seen if t >= 4.3)


# ---------------------------------------------------------------- DO_ORBIT ----------------
def orbit(v, gcs, center_enu, radius_m, speed_m_s, yaw=mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TO_CIRCLE_CENTER):
    lat, lon, _ = local_to_geodetic(v.origin, *center_enu)
    return send(v, gcs, mavlink.MAV_CMD_DO_ORBIT, radius_m, speed_m_s, yaw, 0, lat, lon, math.nan)


def test_do_orbit_is_refused_on_the_ground(vehicle, gcs):
    assert orbit(vehicle, gcs, (100, 120), 20.0, 3.0) == mavlink.MAV_RESULT_DENIED
    assert vehicle.mode is not FlightMode.ORBIT


# (plant, radius tolerance m, speed tolerance m/s, angle tolerance): the multicopter's velocity loop
# lags in the turn (as PX4's), so it rides the circle a little wide and slow.
ORBIT_TOLERANCES = {"unicycle": (1.0, 0.3, 0.1), "multicopter": (1.5, 0.45, 0.2)}


@pytest.mark.parametrize("plant", sorted(ORBIT_TOLERANCES))
@pytest.mark.parametrize("radius_m", [20.0, -20.0])
def test_do_orbit_flies_the_circle_facing_its_centre_in_orbit_mode(mission, make_vehicle, gcs, radius_m, plant):
    vehicle = make_vehicle(replace(mission, plant=Plant(plant)))
    r_tol, v_tol, turn_rel = ORBIT_TOLERANCES[plant]
    airborne(vehicle, gcs)
    center = (100.0, 130.0)  # 30 m north of the vehicle: it first closes to the radius
    assert orbit(vehicle, gcs, center, radius_m, 3.0) == mavlink.MAV_RESULT_ACCEPTED
    assert vehicle.mode is FlightMode.ORBIT
    (hb,) = vehicle.build(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    assert decode_custom_mode(hb.custom_mode) == (Px4MainMode.POSCTL, Px4PosctlSubMode.ORBIT)
    step_for(vehicle, 40.0)
    angles = []
    for _ in range(100):
        step_for(vehicle, 0.2)
        x, y, alt = vehicle.position_enu_m
        s = vehicle.state
        assert math.hypot(x - center[0], y - center[1]) == pytest.approx(abs(radius_m), abs=r_tol)
        assert s.ground_speed_m_s == pytest.approx(3.0, abs=v_tol) and alt == pytest.approx(10.0, abs=0.3)
        to_center_ned = math.atan2(center[0] - x, center[1] - y)  # yaw of the centre, from north to east
        assert abs(wrap_pi(s.yaw_rad - to_center_ned)) < math.radians(10)
        angles.append(math.atan2(y - center[1], x - center[0]))  # ENU angle: CCW positive
    turned = sum(wrap_pi(b - a) for a, b in zip(angles, angles[1:]))
    assert turned == pytest.approx(-math.copysign(20.0 * 3.0 / 20.0, radius_m), rel=turn_rel)  # clockwise for r > 0


def test_a_mode_switch_ends_the_orbit(vehicle, gcs):
    airborne(vehicle, gcs)
    assert orbit(vehicle, gcs, (100, 130), 20.0, 3.0) == mavlink.MAV_RESULT_ACCEPTED
    step_for(vehicle, 10.0)
    hold = send(vehicle, gcs, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)
    assert hold == mavlink.MAV_RESULT_ACCEPTED and vehicle.mode is FlightMode.HOLD
    step_for(vehicle, 10.0)
    assert vehicle.state.ground_speed_m_s < 0.1


# ---------------------------------------------------------------- position + velocity -----
def test_position_and_velocity_setpoint_flies_to_the_position_with_the_velocity_as_feed_forward(vehicle, gcs):
    """MAVSDK's offboard_position_velocity_ned example: the vehicle stops near the position."""
    airborne(vehicle, gcs)
    n0, e0 = vehicle.state.north_m, vehicle.state.east_m
    mask = 0xDC0  # what MAVSDK set_position_velocity_ned sends: position + velocity + yaw

    def setpoint():
        return gcs.wire(gcs.enc.set_position_target_local_ned_encode(
            0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, n0 + 30.0, e0, -10.0, 1.0, 0.0, 0.0, 0, 0, 0, 0.0, 0))

    vehicle.handle(setpoint(), "api")
    ack = send(vehicle, gcs, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
               Px4MainMode.OFFBOARD, 0)
    assert ack == mavlink.MAV_RESULT_ACCEPTED
    peak = 0.0
    for _ in range(600):  # 60 s, a setpoint every 0.1 s
        vehicle.handle(setpoint(), "api")
        step_for(vehicle, 0.1)
        peak = max(peak, vehicle.state.ground_speed_m_s)
    s = vehicle.state
    assert s.north_m - n0 == pytest.approx(31.0, abs=0.3)  # v_ff / Kp beyond, as a P controller with feed-forward
    assert s.east_m == pytest.approx(e0, abs=0.3) and s.ground_speed_m_s < 0.05
    assert peak > 5.0  # it flew there, not crept at the feed-forward speed


# ---------------------------------------------------------------- parameters --------------
def read_param(v, gcs, name):
    emits = v.handle(gcs.wire(gcs.enc.param_request_read_encode(1, 1, name.encode(), -1)), "api")
    (pv,) = [e.msg for e in emits]
    if pv.param_type == mavlink.MAV_PARAM_TYPE_INT32:
        return struct.unpack("<i", struct.pack("<f", pv.param_value))[0], pv.param_type
    return pv.param_value, pv.param_type


@pytest.mark.parametrize("name", sorted(PX4_DEFAULTS))
def test_issue_11_parameters_read_with_px4_names_types_and_defaults_and_set(vehicle, gcs, name):
    value, ptype = read_param(vehicle, gcs, name)  # the mission's plant is the multicopter (the default)
    want = PX4_DEFAULTS[name]
    assert value == pytest.approx(want, rel=1e-6)
    assert ptype == (mavlink.MAV_PARAM_TYPE_INT32 if name in INT_PARAMS else mavlink.MAV_PARAM_TYPE_REAL32)
    if name == "MAV_SYS_ID":
        return  # bound to the link
    new = want + 1
    wire = struct.unpack("<f", struct.pack("<i", int(new)))[0] if name in INT_PARAMS else float(new)
    vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, name.encode(), wire, ptype)), "api")
    assert read_param(vehicle, gcs, name)[0] == pytest.approx(new) and vehicle.param(name) == pytest.approx(new)


def test_the_multicopter_plant_gets_px4s_limits_and_the_unicycle_the_missions():
    from sim_bridge.vehicle.px4 import default_params

    def table(tuned: bool) -> dict[str, float]:
        return {d.name: d.default for d in default_params(1, 10.0, 10.0 / 30.0, 8.0, 30.0, mission_tuned=tuned)}

    px4, mission = table(False), table(True)
    assert {k: px4[k] for k in MISSION_TUNED} == {"MPC_XY_VEL_MAX": 12.0, "MPC_XY_CRUISE": 5.0, "MPC_ACC_HOR": 3.0,
                                                   "MPC_YAWRAUTO_MAX": 60.0}
    assert {k: mission[k] for k in MISSION_TUNED} == pytest.approx(MISSION_TUNED)
    assert px4["RTL_RETURN_ALT"] == mission["RTL_RETURN_ALT"] == 30.0  # the mission's cruise altitude either way
    assert {k: v for k, v in px4.items() if k not in MISSION_TUNED} == {k: v for k, v in mission.items()
                                                                         if k not in MISSION_TUNED}


@pytest.mark.parametrize("plant", ["multicopter", "unicycle"])
def test_each_vehicle_reads_the_limits_of_its_missions_plant(make_vehicle, gcs, plant):
    """The stub's parameter table follows the mission's plant: PX4's defaults on the multicopter."""
    v = make_vehicle(parse_mission(MISSION_YAML + f"plant: {plant}\n", "px4.yaml"), booted=False)
    want = MISSION_TUNED if plant == "unicycle" else {k: PX4_DEFAULTS[k] for k in MISSION_TUNED}
    assert {k: read_param(v, gcs, k)[0] for k in MISSION_TUNED} == pytest.approx(want)
    assert v.limits.max_speed_m_s == pytest.approx(want["MPC_XY_VEL_MAX"])
