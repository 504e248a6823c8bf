"""An unmodified MAVSDK 4.x client (mavsdk.asyncio) flies the stub over real UDP.

Each test starts the stub on free ports and one Mavsdk instance per vehicle, as the companion
does (``udpin://0.0.0.0:<port>``). Expectations come from the mission and from the stub's own
ground truth, never from the client alone.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from typing import Any

import pytest
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import FixType, FlightMode, LandedState, TelemetryAsync

from uav_model.frames import local_to_geodetic
from uav_model.mission import Mission, parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.vehicle.px4 import FlightMode as StubMode
from sim_bridge.testing import sim_connection_url, stub_on_free_ports

from mavsdk_helpers import arm_and_take_off, first, mavsdk_client, quantize, wait_until

# The link contract is asserted with the unicycle's exact kinematics (8.00 m/s in a turn, the yaw
# rate clipped to v/r); the multicopter's responses are in test_sim_multicopter.py.
MISSION_YAML = """
name: mavsdk_scenario
plant: unicycle
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000, geofence_margin_m: 100}
stations: {A: [100, 100], B: [900, 900]}
obstacles:
  - {id: hill, shape: circle, center: [500, 300], radius_m: 50}
  - id: drifter
    shape: circle
    center: [200, 700]
    radius_m: 30
    motion: {type: shuttle, to: [600, 700], speed_m_s: 3}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 8,
     initial_heading_deg: 45, battery_pct: 100}
  - {name: b, start: B, goal: A, speed_m_s: 10, turn_radius_m: 30, cruise_alt_m: 8,
     initial_heading_deg: -135, battery_pct: 35}
"""


@pytest.fixture(scope="module")
def mission() -> Mission:
    return parse_mission(MISSION_YAML, "mavsdk_scenario.yaml")


# ---------------------------------------------------------------- (1) connect, health ------
@pytest.mark.timeout(60)
def test_mavsdk_connects_to_each_vehicle_and_sees_health_home_position_battery_mode(mission):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0)) as sim:
            for i, spec in enumerate(mission.vehicles):
                async with mavsdk_client(sim_connection_url(sim, i)) as system:
                    tel = TelemetryAsync(system)
                    assert await system.get_system_id() == spec.system_id
                    await first(tel.subscribe_health_all_ok(), bool)
                    health = await tel.health()
                    assert all(vars(health).values()), health
                    lat, lon, alt = local_to_geodetic(mission.origin, *spec.start_enu_m)
                    home = await first(tel.subscribe_home())
                    assert (home.latitude_deg, home.longitude_deg) == pytest.approx((quantize(lat), quantize(lon)), abs=1e-9)
                    assert home.absolute_altitude_m == pytest.approx(alt, abs=0.01)
                    pos = await first(tel.subscribe_position())
                    assert (pos.latitude_deg, pos.longitude_deg) == pytest.approx((lat, lon), abs=2e-7)
                    assert pos.relative_altitude_m == pytest.approx(0.0, abs=0.01)
                    ned = await first(tel.subscribe_position_velocity_ned())
                    assert (ned.position.east_m, ned.position.north_m) == pytest.approx(spec.start_enu_m, abs=0.01)
                    bat = await first(tel.subscribe_battery())
                    assert bat.remaining_percent == pytest.approx(spec.battery_pct, abs=0.5)
                    assert await first(tel.subscribe_flight_mode()) == FlightMode.HOLD
                    assert await first(tel.subscribe_landed_state()) == LandedState.ON_GROUND
                    assert await first(tel.subscribe_armed()) is False
                    gps = await first(tel.subscribe_gps_info())
                    assert gps.fix_type == FixType.FIX_3D and gps.num_satellites >= 6
            assert sim.stats["garbage"] == 0 and sim.stats["loop_errors"] == 0

    asyncio.run(scenario())


# ---------------------------------------------------------------- (2) commands, offboard ---
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_mavsdk_arms_takes_off_flies_offboard_body_and_ned_holds_and_lands(mission):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=10.0)) as sim:
            v = sim.vehicle("a")
            async with mavsdk_client(sim_connection_url(sim, 0)) as system:
                tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
                await act.set_takeoff_altitude(6.0)
                assert v.param("MIS_TAKEOFF_ALT") == 6.0 and await act.get_takeoff_altitude() == 6.0
                await arm_and_take_off(system, sim, 0)
                assert v.position_enu_m[2] == pytest.approx(6.0, abs=0.3)
                assert await first(tel.subscribe_landed_state(), lambda s: s == LandedState.IN_AIR)

                # Body frame: 8 m/s forward while yawing at 15 deg/s (within v/r = 19.1 deg/s).
                await off.set_velocity_body(VelocityBodyYawspeed(8.0, 0.0, 0.0, 15.0))
                await off.start()
                await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.OFFBOARD, 2.0)
                await wait_until(sim, lambda: v.state.ground_speed_m_s > 7.99, 5.0, "cruise speed")
                yaw0, t0 = v.state.yaw_rad, sim.sim_time_s
                await wait_until(sim, lambda: sim.sim_time_s > t0 + 6.0, 5.0, "6 s of sim time")
                turned = math.remainder(v.state.yaw_rad - yaw0, 2 * math.pi)
                assert turned == pytest.approx(math.radians(15.0) * (sim.sim_time_s - t0), abs=math.radians(3))
                vel = (await first(tel.subscribe_position_velocity_ned())).velocity
                assert math.hypot(vel.north_m_s, vel.east_m_s) == pytest.approx(8.0, abs=0.05)
                # Beyond the turn-rate limit the vehicle turns at v/r, no faster.
                await off.set_velocity_body(VelocityBodyYawspeed(8.0, 0.0, 0.0, 90.0))
                await wait_until(sim, lambda: abs(v.state.yawspeed_rad_s) > 0.3, 3.0, "fast yaw command")
                assert abs(v.state.yawspeed_rad_s) == pytest.approx(10.0 / 30.0)

                # NED frame with a yaw ANGLE (what set_velocity_ned sends): fly east facing east.
                await off.set_velocity_ned(VelocityNedYaw(0.0, 5.0, 0.0, 90.0))
                await wait_until(sim, lambda: abs(v.state.yaw_rad - math.pi / 2) < 1e-3
                                 and abs(v.state.ve_m_s - 5.0) < 1e-3, 10.0, "east at 5 m/s facing east")
                heading = await first(tel.subscribe_heading())
                assert heading.heading_deg == pytest.approx(90.0, abs=0.5)
                assert v.state.vn_m_s == pytest.approx(0.0, abs=1e-3)

                await off.stop()  # MAVSDK switches to Hold
                await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 2.0)
                await wait_until(sim, lambda: v.state.ground_speed_m_s < 0.05, 10.0, "hold to settle")
                held = v.position_enu_m
                await asyncio.sleep(0.5)
                assert v.position_enu_m == pytest.approx(held, abs=0.1)

                await act.land()
                await first(tel.subscribe_in_air(), lambda air: not air, 30.0)
                await first(tel.subscribe_armed(), lambda armed: not armed, 10.0)  # auto-disarm
                assert v.position_enu_m[:2] == pytest.approx(held[:2], abs=0.5)
                assert v.collision_count == 0 and v.offboard_losses == []
                assert v.counters["handler_error"] == 0 and sim.stats["loop_errors"] == 0

    asyncio.run(scenario())


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_companion_crash_fails_safe_to_rtl_after_com_of_loss_t_times_the_speed_factor(mission):
    """The client dies mid-offboard: PX4's default failsafe (RTL) COM_OF_LOSS_T x speed factor
    (+ one physics tick) of sim time after the last setpoint, i.e. ~COM_OF_LOSS_T of wall time."""
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0)) as sim:
            v = sim.vehicle("b")
            async with mavsdk_client(sim_connection_url(sim, 1)) as system:
                await arm_and_take_off(system, sim, 1)
                off = OffboardAsync(system)
                await off.set_velocity_body(VelocityBodyYawspeed(5.0, 0.0, 0.0, 0.0))
                await off.start()
                await wait_until(sim, lambda: v.mode is StubMode.OFFBOARD, 2.0, "OFFBOARD")
                await asyncio.sleep(0.5)
            # The Mavsdk instance is gone: no more setpoints, no offboard.stop().
            await wait_until(sim, lambda: v.mode is StubMode.RTL, 5.0, "failsafe to RTL")
            (loss,) = v.offboard_losses
            timeout, tick = v.param("COM_OF_LOSS_T") * sim.options.speedup, sim.options.physics_dt_s
            assert timeout < loss.failsafe_t_s - loss.last_setpoint_t_s <= timeout + tick + 1e-9
            assert v.in_air and v.armed

    asyncio.run(scenario())


@pytest.mark.timeout(60)
def test_offboard_is_refused_without_a_setpoint_stream_and_commands_are_acked(mission):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0)) as sim:
            async with mavsdk_client(sim_connection_url(sim, 0)) as system:
                from mavsdk.asyncio.plugins.offboard import OffboardError

                tel, act = TelemetryAsync(system), ActionAsync(system)
                await first(tel.subscribe_health_all_ok(), bool)
                # MAVSDK refuses locally without a setpoint (the stub's own refusal of a stale
                # stream is covered in tests/sim_bridge/test_sim_vehicle.py).
                with pytest.raises(OffboardError):
                    await OffboardAsync(system).start()
                # RTL on the ground: MAVSDK switches modes with DO_SET_MODE, which PX4 ACKs ACCEPTED
                # and then refuses ("... is currently not available"); the mode does not change.
                await act.return_to_launch()
                await act.arm()
                await act.disarm()  # landed: allowed
                assert sim.vehicle(0).mode is StubMode.HOLD

    asyncio.run(scenario())


# ---------------------------------------------------------------- (3) missions -------------
def mission_item(mission: Mission, x_m: float, y_m: float, alt_m: float, **kw: Any) -> MissionItem:
    lat, lon, _ = local_to_geodetic(mission.origin, x_m, y_m)
    defaults: dict[str, Any] = dict(
        speed_m_s=math.nan, is_fly_through=True, gimbal_pitch_deg=math.nan, gimbal_yaw_deg=math.nan,
        camera_action=MissionItem.CameraAction.NONE, loiter_time_s=math.nan, camera_photo_interval_s=1.0,
        acceptance_radius_m=4.0, yaw_deg=math.nan, camera_photo_distance_m=math.nan,
        vehicle_action=MissionItem.VehicleAction.NONE)
    defaults.update(kw)
    return MissionItem(quantize(lat), quantize(lon), alt_m, **defaults)


def item_differences(a: MissionItem, b: MissionItem) -> dict[str, tuple[Any, Any]]:
    def eq(x: Any, y: Any) -> bool:
        return (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)) or x == y
    return {k: (x, vars(b)[k]) for k, x in vars(a).items() if not eq(x, vars(b)[k])}


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_mavsdk_uploads_downloads_identical_and_flies_the_mission_to_completion(mission):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=20.0)) as sim:
            v = sim.vehicle("a")  # station A is (100, 100)
            # MAVSDK does not carry an acceptance radius for TAKEOFF / LAND items (it reads 1 m back).
            plan = MissionPlan([
                mission_item(mission, 100, 100, 10.0, vehicle_action=MissionItem.VehicleAction.TAKEOFF,
                             is_fly_through=False, acceptance_radius_m=1.0),
                mission_item(mission, 100, 250, 12.5, speed_m_s=8.0),
                mission_item(mission, 250, 250, 12.5, is_fly_through=False, loiter_time_s=2.0),
                mission_item(mission, 250, 150, 10.0),
                mission_item(mission, 200, 150, 10.0, vehicle_action=MissionItem.VehicleAction.LAND,
                             is_fly_through=False, acceptance_radius_m=1.0),
            ])
            async with mavsdk_client(sim_connection_url(sim, 0)) as system:
                tel, act, mis = TelemetryAsync(system), ActionAsync(system), MissionAsync(system)
                await first(tel.subscribe_health_all_ok(), bool)
                await mis.upload_mission(plan)
                stored = v.missions.plan()
                assert len(stored) >= len(plan.mission_items)  # MAVSDK adds DO_CHANGE_SPEED items
                downloaded = await mis.download_mission()
                assert len(downloaded.mission_items) == len(plan.mission_items)
                for sent, got in zip(plan.mission_items, downloaded.mission_items):
                    assert item_differences(sent, got) == {}

                await act.arm()
                progress = []
                await mis.start_mission()
                async with contextlib.aclosing(mis.subscribe_mission_progress()) as updates:
                    async with asyncio.timeout(60.0):
                        async for p in updates:
                            progress.append((p.current, p.total))
                            if p.current == p.total:
                                break
                assert progress[-1] == (5, 5) and [c for c, _ in progress] == sorted(c for c, _ in progress)
                assert await mis.is_mission_finished()
                await first(tel.subscribe_armed(), lambda armed: not armed, 20.0)  # landed, auto-disarmed
                # PX4 stays in MISSION after a mission's landing (and its disarm).
                assert v.mode is StubMode.MISSION and v.position_enu_m == pytest.approx((200.0, 150.0, 0.0), abs=1.0)
                assert v.collision_count == 0 and v.missions.counters["upload_timeout"] == 0

                # Clearing works too, and an empty plan cannot be started.
                await mis.clear_mission()
                assert v.missions.plan() == ()
                assert (await mis.download_mission()).mission_items == []

    asyncio.run(scenario())
