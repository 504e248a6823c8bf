"""The stub flying the default multicopter plant: PX4's responses to the characterisation's commands.

The numbers are PX4 SITL's (../shared/px4-sih/README.md): a 10 m/s + 19.1 deg/s body command
settles at 7.4-8.2 m/s; 15 m/s gives 9.6-9.8 m/s; a yaw in place reaches 86-90 deg/s for 90,
limited by MC_YAWRATE_MAX and not by the mission's turn radius. The state machine is unchanged.
"""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink
from test_sim_vehicle import (MISSION_YAML, enter_offboard, fly_offboard, run, send, setpoint_body, setpoint_ned_yaw,
                              takeoff)

from uav_model.mission import parse_mission
from uav_model.plant import MulticopterLimits, Plant
from sim_bridge.vehicle.px4 import FlightMode

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def vehicle(make_vehicle):
    mission = parse_mission(MISSION_YAML.replace("plant: unicycle", "plant: multicopter"), "unit.yaml")
    assert mission.plant is Plant.MULTICOPTER
    return make_vehicle(mission)


def _offboard(v, gcs, fwd, yaw_rate, seconds):
    make = lambda: setpoint_body(gcs, fwd, 0.0, 0.0, yaw_rate)  # noqa: E731
    enter_offboard(v, gcs, make)
    yaws = []
    fly_offboard(v, gcs, make, seconds, check=lambda v: yaws.append(v.state.yaw_rad))
    return yaws


def test_the_stub_flies_the_multicopter_with_px4_limits(vehicle):
    assert isinstance(vehicle.limits, MulticopterLimits)
    assert vehicle.limits.max_yaw_rate_rad_s == pytest.approx(math.radians(200.0))  # MC_YAWRATE_MAX


def test_turn_settles_slower_than_commanded_as_on_px4(vehicle, gcs):
    takeoff(vehicle, gcs)
    yaws = _offboard(vehicle, gcs, 10.0, math.radians(-19.1), 12.0)
    assert 7.4 <= vehicle.state.ground_speed_m_s <= 8.2
    late = yaws[-250:]  # the last 5 s: the heading keeps the commanded rate
    rate = sum(math.remainder(b - a, 2 * math.pi) for a, b in zip(late, late[1:])) / (0.02 * (len(late) - 1))
    assert math.degrees(rate) == pytest.approx(-19.1, rel=0.05)


def test_yaw_in_place_is_not_limited_by_the_mission_turn_radius(vehicle, gcs):
    takeoff(vehicle, gcs)
    _offboard(vehicle, gcs, 0.0, math.radians(90.0), 4.0)
    assert 86.0 <= math.degrees(vehicle.state.yawspeed_rad_s) <= 90.0  # the mission's v/r is 19.1


def test_a_yaw_angle_setpoint_turns_within_mpc_yawrauto_max_without_overshoot(vehicle, gcs):
    """Auto-mode yaw on the lagging heading rate: settles on the angle, no swing past it."""
    takeoff(vehicle, gcs)
    target = vehicle.state.yaw_rad + math.radians(120.0)
    make = lambda: setpoint_ned_yaw(gcs, 0.0, 0.0, 0.0, target)  # noqa: E731
    enter_offboard(vehicle, gcs, make)
    errors, rates = [], []
    fly_offboard(vehicle, gcs, make, 15.0, check=lambda v: (errors.append(math.remainder(v.state.yaw_rad - target, 2 * math.pi)),
                                                           rates.append(abs(v.state.yawspeed_rad_s))))
    assert max(rates) <= math.radians(vehicle.param("MPC_YAWRAUTO_MAX")) + 1e-9
    assert abs(errors[-1]) < math.radians(0.5) and max(errors) < math.radians(3.0)  # approaches from below


def test_over_speed_is_held_to_the_tilt_limited_speed(vehicle, gcs):
    # PX4's MPC_XY_VEL_MAX 12, the multicopter's default; the plant flies the parameter, so 11 set
    # over the parameter protocol changes nothing here: the tilt limit holds less than either.
    assert vehicle.param("MPC_XY_VEL_MAX") == 12.0
    vehicle.handle(gcs.wire(gcs.enc.param_set_encode(1, 1, b"MPC_XY_VEL_MAX", 11.0, mavlink.MAV_PARAM_TYPE_REAL32)), "api")
    assert vehicle.limits.mpc_xy_vel_max == 11.0
    takeoff(vehicle, gcs)
    _offboard(vehicle, gcs, 15.0, 0.0, 8.0)
    assert 9.6 <= vehicle.state.ground_speed_m_s <= 9.8


def test_hold_after_flight_brakes_to_a_stop_and_land_disarms(vehicle, gcs):
    takeoff(vehicle, gcs)
    _offboard(vehicle, gcs, 8.0, 0.0, 5.0)
    ack = send(vehicle, gcs, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED and vehicle.mode is FlightMode.HOLD
    run(vehicle, 15.0)
    assert vehicle.state.ground_speed_m_s < 0.1
    assert send(vehicle, gcs, mavlink.MAV_CMD_NAV_LAND).result == mavlink.MAV_RESULT_ACCEPTED
    run(vehicle, 60.0, until=lambda v: not v.armed)
    assert not vehicle.armed and not vehicle.in_air
