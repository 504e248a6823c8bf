"""What MAVSDK-Python's examples do, done by the real MAVSDK against the stub over real UDP.

One test per example (takeoff_and_land, offboard_position_ned, offboard_position_velocity_ned,
goto, mission_raw, mission_import, geofence, telemetry, params, firmware_version, orbit), each
a few seconds at a speed factor; offboard velocity in body and NED frames and the mission
plugin are in test_sim_bridge_mavsdk.py. Expectations come from the stub's ground truth and from
PX4's measured behaviour (../shared/px4-sih/README.md), never from the client alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from mavsdk.asyncio.plugins.action import ActionAsync, OrbitYawBehavior
from mavsdk.asyncio.plugins.geofence import Circle, FenceType, GeofenceAsync, GeofenceData, Point, Polygon
from mavsdk.asyncio.plugins.info import InfoAsync
from mavsdk.asyncio.plugins.mission_raw import MissionItem as RawItem
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw, VelocityNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import geodetic_to_local, local_to_geodetic
from uav_model.mission import Mission, parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.vehicle.mission_protocol import FENCE
from sim_bridge.vehicle.px4 import FlightMode as StubMode
from sim_bridge.testing import sim_connection_url, stub_on_free_ports

from mavsdk_helpers import arm_and_take_off, first, mavsdk_client, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]

PLAN = Path(__file__).resolve().parents[1] / "data" / "small_mission.plan"
MISSION_YAML = """
name: mavsdk_examples
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 10}
"""
SPEEDUP = 10.0


@pytest.fixture(scope="module")
def mission() -> Mission:
    return parse_mission(MISSION_YAML, "mavsdk_examples.yaml")


def run(mission: Mission, scenario, speedup: float = SPEEDUP) -> None:
    """Start the stub, connect MAVSDK to vehicle a, run ``scenario(sim, vehicle, system)``."""
    import asyncio

    async def main():
        async with stub_on_free_ports(mission, SimOptions(speedup=speedup)) as sim:
            async with mavsdk_client(sim_connection_url(sim, 0)) as system:
                await scenario(sim, sim.vehicle(0), system)
            assert sim.stats["loop_errors"] == 0 and sim.vehicle(0).counters["handler_error"] == 0

    asyncio.run(main())


def lat_lon(mission: Mission, x_m: float, y_m: float) -> tuple[float, float]:
    lat, lon, _ = local_to_geodetic(mission.origin, x_m, y_m)
    return lat, lon


async def take_off(sim, system, alt_m: float = 10.0) -> None:
    await ActionAsync(system).set_takeoff_altitude(alt_m)
    await arm_and_take_off(system, sim, 0)
    await wait_until(sim, lambda: sim.vehicle(0).position_enu_m[2] > alt_m - 0.3, 5.0, "take-off altitude")


async def start_offboard(system, sim, first_setpoint) -> OffboardAsync:
    off = OffboardAsync(system)
    await first_setpoint(off)
    await off.start()
    await first(TelemetryAsync(system).subscribe_flight_mode(), lambda m: m == FlightMode.OFFBOARD, 5.0)
    return off


# ---------------------------------------------------------------- takeoff_and_land.py ------
def test_takeoff_and_land_to_px4s_default_takeoff_altitude(mission):
    async def scenario(sim, v, system):
        tel, act = TelemetryAsync(system), ActionAsync(system)
        await first(tel.subscribe_health_all_ok(), bool)
        await act.arm()
        await act.takeoff()  # no altitude set: PX4's MIS_TAKEOFF_ALT 2.5 m
        await first(tel.subscribe_in_air(), bool, 10.0)
        await wait_until(sim, lambda: v.mode is StubMode.HOLD and v.in_air, 30.0, "take-off done")
        assert v.position_enu_m[2] == pytest.approx(2.5, abs=0.3)
        await act.land()
        await first(tel.subscribe_in_air(), lambda air: not air, 20.0)
        await first(tel.subscribe_armed(), lambda armed: not armed, 10.0)
        assert v.position_enu_m[2] == pytest.approx(0.0, abs=0.05)

    run(mission, scenario)


# ---------------------------------------------------------------- offboard_position_ned.py -
def test_offboard_position_ned_reaches_each_position(mission):
    async def scenario(sim, v, system):
        await take_off(sim, system)
        n0, e0 = v.state.north_m, v.state.east_m
        off = await start_offboard(system, sim, lambda o: o.set_position_ned(PositionNedYaw(n0, e0, -10.0, 0.0)))
        for dn, de, yaw in ((20.0, 0.0, 0.0), (20.0, 20.0, 90.0), (0.0, 20.0, 180.0)):
            await off.set_position_ned(PositionNedYaw(n0 + dn, e0 + de, -10.0, yaw))
            await wait_until(sim, lambda: math.hypot(v.state.north_m - n0 - dn, v.state.east_m - e0 - de) < 0.2
                             and v.state.ground_speed_m_s < 0.1, 10.0, f"position ({dn}, {de})")
            assert abs(math.remainder(math.degrees(v.state.yaw_rad) - yaw, 360.0)) < 1.0
        await off.stop()

    run(mission, scenario)


# ---------------------------------------------------------------- offboard_position_velocity_ned.py
def test_offboard_position_velocity_ned_uses_the_velocity_as_feed_forward(mission):
    """The example sends a position 50 m away with 1 m/s toward it: PX4 flies there and stops."""
    async def scenario(sim, v, system):
        await take_off(sim, system)
        n0, e0 = v.state.north_m, v.state.east_m
        hold = PositionNedYaw(n0, e0, -10.0, 0.0)
        off = await start_offboard(system, sim,
                                   lambda o: o.set_position_velocity_ned(hold, VelocityNedYaw(0.0, 0.0, 0.0, 0.0)))
        await off.set_position_velocity_ned(PositionNedYaw(n0 + 50.0, e0, -10.0, 0.0), VelocityNedYaw(1.0, 0.0, 0.0, 0.0))
        await wait_until(sim, lambda: v.state.ground_speed_m_s > 5.0, 5.0, "flying toward the position")
        await wait_until(sim, lambda: v.state.north_m > n0 + 45.0 and v.state.ground_speed_m_s < 0.05, 20.0,
                         "stopped at the position")
        # Just past it: v_ff / Kp = 1 m on the unicycle, ~3 m on the multicopter, whose velocity loop lags.
        assert 50.5 < v.state.north_m - n0 < 54.0
        assert v.state.east_m == pytest.approx(e0, abs=0.3)
        await off.stop()

    run(mission, scenario)


# ---------------------------------------------------------------- goto.py ------------------
def test_goto_location_flies_there_and_holds(mission):
    async def scenario(sim, v, system):
        await take_off(sim, system)
        lat, lon = lat_lon(mission, 160.0, 140.0)
        await ActionAsync(system).goto_location(lat, lon, mission.origin.alt_m + 15.0, 0.0)
        await wait_until(sim, lambda: math.dist(v.position_enu_m, (160.0, 140.0, 15.0)) < 0.3, 20.0, "goto target")
        assert v.mode is StubMode.HOLD
        assert await first(TelemetryAsync(system).subscribe_flight_mode()) == FlightMode.HOLD

    run(mission, scenario)


# ---------------------------------------------------------------- mission_raw.py, mission_import.py
def raw_waypoint(mission: Mission, seq: int, x_m: float, y_m: float, alt_m: float, command: int) -> RawItem:
    lat, lon = lat_lon(mission, x_m, y_m)
    return RawItem(seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 1 if seq == 0 else 0, 1,
                   0.0, 2.0, 0.0, math.nan, int(round(lat * 1e7)), int(round(lon * 1e7)), alt_m, 0)


def test_mission_raw_upload_download_and_fly(mission):
    async def scenario(sim, v, system):
        raw = MissionRawAsync(system)
        items = [raw_waypoint(mission, 0, 100, 100, 10.0, mavlink.MAV_CMD_NAV_TAKEOFF),
                 raw_waypoint(mission, 1, 100, 150, 10.0, mavlink.MAV_CMD_NAV_WAYPOINT),
                 raw_waypoint(mission, 2, 150, 150, 10.0, mavlink.MAV_CMD_NAV_WAYPOINT),
                 raw_waypoint(mission, 3, 150, 150, 0.0, mavlink.MAV_CMD_NAV_LAND)]
        await first(TelemetryAsync(system).subscribe_health_all_ok(), bool)
        await raw.upload_mission(items)
        back = await raw.download_mission()
        assert [(i.command, i.x, i.y, i.z) for i in back] == [(i.command, i.x, i.y, i.z) for i in items]
        await ActionAsync(system).arm()
        await raw.start_mission()
        await wait_until(sim, lambda: v.mission_finished and not v.armed, 40.0, "mission flown and landed")
        assert v.position_enu_m == pytest.approx((150.0, 150.0, 0.0), abs=1.0)

    run(mission, scenario, speedup=20.0)


def test_mission_import_of_a_qgroundcontrol_plan_uploads_what_the_plan_says(mission):
    async def scenario(sim, v, system):
        raw = MissionRawAsync(system)
        imported = await raw.import_qgroundcontrol_mission(str(PLAN))
        assert [i.command for i in imported.mission_items] == [mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_WAYPOINT,
                                                               mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LAND]
        await raw.upload_mission(imported.mission_items)
        stored = v.missions.plan()
        assert [it.command for it in stored] == [i.command for i in imported.mission_items]
        x, y, _ = geodetic_to_local(mission.origin, stored[2].lat_deg, stored[2].lon_deg)
        assert (x, y, stored[2].z) == pytest.approx((160.0, 160.0, 12.0), abs=0.5)  # the plan's third item
        await ActionAsync(system).arm()
        await raw.start_mission()
        await wait_until(sim, lambda: v.mission_finished and not v.armed, 40.0, "imported mission flown")
        assert v.position_enu_m[:2] == pytest.approx((160.0, 100.0), abs=1.0)

    run(mission, scenario, speedup=20.0)


# ---------------------------------------------------------------- geofence.py --------------
def test_geofence_polygon_and_circle_are_stored_and_a_radius_0_circle_too(mission):
    """geofence.py's polygon and circle; then a radius-0 circle, which PX4 stores.

    MAVSDK 4.1's Geofence plugin refuses a radius-0 circle itself (INVALID_ARGUMENT, nothing is
    sent), so that one goes up through MissionRaw.upload_geofence, as other clients send it.
    """
    async def scenario(sim, v, system):
        await first(TelemetryAsync(system).subscribe_health_all_ok(), bool)
        lat, lon = lat_lon(mission, 100.0, 100.0)
        d = 0.0001
        polygon = Polygon([Point(lat - d, lon - d), Point(lat + d, lon - d), Point(lat + d, lon + d),
                           Point(lat - d, lon + d)], FenceType.INCLUSION)
        circle = Circle(Point(lat, lon), 10.0, FenceType.EXCLUSION)
        await GeofenceAsync(system).upload_geofence(GeofenceData([polygon], [circle]))
        fence = v.missions.plan(FENCE)
        assert [it.command for it in fence] == [mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + [
            mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION]
        assert fence[-1].param1 == 10.0 and all(it.param1 == 4.0 for it in fence[:4])

        zero = RawItem(0, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0, 0, 0.0, 0.0, 0.0, 0.0,
                       int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, FENCE)
        await MissionRawAsync(system).upload_geofence([zero])
        (stored,) = v.missions.plan(FENCE)
        assert stored.command == mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION and stored.param1 == 0.0

    run(mission, scenario)


# ---------------------------------------------------------------- telemetry.py -------------
def test_telemetry_as_on_px4_sitl_including_its_simulated_battery(mission):
    async def scenario(sim, v, system):
        tel = TelemetryAsync(system)
        bat = await first(tel.subscribe_battery())
        assert bat.remaining_percent == pytest.approx(100.0)  # the mission sets no charge
        await take_off(sim, system)
        att = await first(tel.subscribe_attitude_euler())
        assert att.yaw_deg == pytest.approx(math.degrees(v.state.yaw_rad), abs=1.0)
        pos = await first(tel.subscribe_position())
        assert pos.relative_altitude_m == pytest.approx(10.0, abs=0.3)
        assert await first(tel.subscribe_flight_mode()) == FlightMode.HOLD
        await first(tel.subscribe_battery(), lambda b: b.remaining_percent <= 50.5, 10.0)  # 60 s armed: 50 %
        await wait_until(sim, lambda: v.battery_pct == 50.0, 2.0, "the battery at SIM_BAT_MIN_PCT")  # reported rounded

    run(mission, scenario, speedup=20.0)


# ---------------------------------------------------------------- params.py ----------------
def test_params_read_and_set_with_px4_names_types_and_defaults(mission):
    async def scenario(sim, v, system):
        par = ParamAsync(system)
        assert await par.get_param_int("COM_OBL_RC_ACT") == 0
        assert await par.get_param_float("COM_OF_LOSS_T") == pytest.approx(1.0)
        assert await par.get_param_float("MC_YAWRATE_MAX") == pytest.approx(200.0)
        assert await par.get_param_int("NAV_RCL_ACT") == 2
        await par.set_param_int("COM_OBL_RC_ACT", 5)
        assert v.param("COM_OBL_RC_ACT") == 5 and await par.get_param_int("COM_OBL_RC_ACT") == 5
        await par.set_param_float("MPC_XY_CRUISE", 7.5)
        assert v.param("MPC_XY_CRUISE") == 7.5
        every = await par.get_all_params()
        names = {p.name for p in every.int_params} | {p.name for p in every.float_params}
        assert {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "COM_RCL_EXCEPT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_RC_IN_MODE",
                "MIS_TAKEOFF_ALT", "MPC_XY_VEL_MAX", "MPC_ACC_HOR", "MPC_ACC_HOR_MAX", "MC_YAWRATE_MAX",
                "MPC_YAWRAUTO_MAX", "COM_DISARM_LAND", "COM_DISARM_PRFLT", "COM_FAIL_ACT_T", "MPC_TKO_SPEED",
                "NAV_ACC_RAD", "MPC_XY_CRUISE", "COM_DL_LOSS_T", "MPC_LAND_SPEED", "COM_SPOOLUP_TIME",
                "SIM_BAT_DRAIN", "SIM_BAT_MIN_PCT", "GF_ACTION"} <= names

    run(mission, scenario)


# ---------------------------------------------------------------- firmware_version.py ------
def test_firmware_version_is_a_px4_release(mission):
    async def scenario(sim, v, system):
        version = await InfoAsync(system).get_version()
        assert (version.flight_sw_major, version.flight_sw_minor, version.flight_sw_patch) == (1, 15, 0)

    run(mission, scenario)


# ---------------------------------------------------------------- orbit.py -----------------
def test_do_orbit_flies_a_circle_facing_its_centre(mission):
    async def scenario(sim, v, system):
        await take_off(sim, system)
        lat, lon = lat_lon(mission, 100.0, 115.0)
        await ActionAsync(system).do_orbit(10.0, 2.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, lat, lon, math.nan)
        await wait_until(sim, lambda: v.mode is StubMode.ORBIT, 2.0, "ORBIT mode")
        assert await first(TelemetryAsync(system).subscribe_flight_mode()) != FlightMode.HOLD
        # The multicopter's lagging velocity loop rides the circle a little wide and slow, as PX4's.
        await wait_until(sim, lambda: abs(math.dist(v.position_enu_m[:2], (100.0, 115.0)) - 10.0) < 1.0
                         and abs(v.state.ground_speed_m_s - 2.0) < 0.3, 20.0, "on the circle at 2 m/s")
        t0 = sim.sim_time_s
        await wait_until(sim, lambda: sim.sim_time_s > t0 + 10.0, 5.0, "10 s of orbit")
        assert abs(math.dist(v.position_enu_m[:2], (100.0, 115.0)) - 10.0) < 1.0
        assert v.position_enu_m[2] == pytest.approx(10.0, abs=0.3)
        await ActionAsync(system).hold()
        await wait_until(sim, lambda: v.mode is StubMode.HOLD, 2.0, "Hold ends the orbit")

    run(mission, scenario)
