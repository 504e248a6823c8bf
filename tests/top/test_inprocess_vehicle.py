"""The in-process Vehicle adapter against the port contract: the stub's own SimVehicles, no sockets.

Every test drives a real :class:`InProcessFleet` (the stub's PX4-like state machine and plant) and
judges the vehicle by its truth (``InProcessVehicle.sim``) as well as by what the port reports.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest

from companion.app.flight_plan import prepare, verify_readback
from companion.cli import main
from companion.errors import CommandRefused, MissionUploadError, VehicleNotReady
from uav_model.mission import load_mission, parse_mission
from companion.sitl.inprocess import InProcessFleet, InProcessOptions, InProcessVehicle, open_inprocess_fleet
from companion.vehicle.port import FlightMode, GeoWaypoint, LandedState, Vehicle, VelocityYawRateSetpoint

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
MOVING = ROOT / "missions" / "moving_obstacles.yaml"
WALL_S = 10.0  # generous wall bound for any one wait: the sim runs ~100x real time


def _fly(mission, body: Callable[[InProcessFleet], Awaitable[object]], options: InProcessOptions | None = None):
    async def go():
        async with asyncio.timeout(60.0):
            async with open_inprocess_fleet(mission, options) as fleet:
                return await body(fleet)
    return asyncio.run(go())


async def _airborne(v: InProcessVehicle, alt_m: float = 12.0) -> None:
    await v.wait_ready(WALL_S)
    await v.arm()
    await v.takeoff(alt_m)
    # EXTENDED_SYS_STATE streams at 2 Hz: IN_AIR may follow the HOLD heartbeat by half a second.
    await v.wait_until(lambda s, p: s.mode is FlightMode.HOLD and s.landed is LandedState.IN_AIR
                       and p is not None and p.alt_rel_m > alt_m - 0.5, WALL_S, "take-off complete")


def test_the_adapter_implements_the_whole_port(reference_mission):
    fleet = InProcessFleet(reference_mission)
    assert isinstance(fleet.vehicle("a"), Vehicle)
    with pytest.raises(KeyError, match="no vehicle 'c'"):
        fleet.vehicle("c")


def test_not_ready_until_the_sim_runs_and_arming_refused_on_an_empty_battery(reference_mission):
    # A fleet whose clock is not driven sends no telemetry: wait_ready names what is missing.
    idle = InProcessFleet(reference_mission)
    with pytest.raises(VehicleNotReady, match="not ok: sensors, home position, global position"):
        asyncio.run(idle.vehicle("a").wait_ready(0.2))

    # PX4 (and the stub) refuse to arm below BAT_CRIT_THR: the same error as over MAVSDK.
    weak = parse_mission(REFERENCE.read_text().replace("battery_pct: 35.0", "battery_pct: 5.0"), source="weak.yaml")

    async def body(fleet):
        b = fleet.vehicle("b")
        await b.wait_ready(WALL_S)
        with pytest.raises(CommandRefused) as refused:
            await b.arm()
        await asyncio.sleep(0)
        return refused.value, b.status(), b.sim.armed
    err, status, armed = _fly(weak, body)
    assert (err.command, err.result, err.retryable, err.vehicle) == ("arm", "COMMAND_DENIED", False, "b")
    assert not status.armed and not armed and status.health_ok


def test_takeoff_climbs_to_the_asked_altitude_then_holds(reference_mission):
    async def body(fleet):
        a = fleet.vehicle("a")
        await _airborne(a, 12.0)
        return a.status(), a.latest_pose(), a.sim
    status, pose, sim = _fly(reference_mission, body)
    assert sim.param("MIS_TAKEOFF_ALT") == 12.0  # set through the param protocol, as MAVSDK does
    assert status.armed and status.landed is LandedState.IN_AIR
    assert pose.alt_rel_m == pytest.approx(-sim.state.down_m, abs=0.5)
    assert pose.alt_rel_m == pytest.approx(12.0, abs=0.3)
    x, y, _ = sim.position_enu_m
    assert math.hypot(pose.x_east_m - x, pose.y_north_m - y) < 0.5  # straight up from home


def test_offboard_start_requires_a_setpoint_and_flies_the_body_command(reference_mission):
    first = VelocityYawRateSetpoint(forward_m_s=6.0, yaw_rate_enu_rad_s=0.2, climb_m_s=0.5)

    async def body(fleet):
        a = fleet.vehicle("a")
        await _airborne(a)
        # PX4 ACKs the switch ACCEPTED without a setpoint stream, then refuses it: only the heartbeat tells.
        await a.set_mode(FlightMode.OFFBOARD, "offboard start")
        t = a.clock_s()
        await a.wait_until(lambda s, p: p is not None and p.t_sim_s > t + 1.5, WALL_S, "a heartbeat later")
        assert a.status().mode is FlightMode.HOLD
        start = a.latest_pose()
        await a.start_offboard(first)
        await a.wait_until(lambda s, p: s.mode is FlightMode.OFFBOARD, WALL_S, "OFFBOARD in the next heartbeat")
        sent = a.sim.setpoint
        while (p := await a.next_pose(a.latest_pose().seq, WALL_S)).t_sim_s < start.t_sim_s + 3.0:
            await a.send_setpoint(first)
        return sent, start, p
    sent, start, end = _fly(reference_mission, body)
    # BODY_NED velocity, down = -climb, PX4's clockwise yawspeed = -(CCW yaw rate).
    assert sent.body and (sent.vx_m_s, sent.vy_m_s, sent.vz_m_s) == (6.0, 0.0, -0.5)
    assert sent.yaw_rate_rad_s == pytest.approx(-0.2)
    turned = (end.heading_enu_rad - start.heading_enu_rad) % (2 * math.pi)
    assert 0.4 < turned < 0.7  # counter-clockwise in ENU at ~0.2 rad/s for ~3 s
    assert end.ground_speed_m_s == pytest.approx(6.0, abs=0.3) and end.alt_rel_m > start.alt_rel_m + 0.8
    # The reported ENU velocity points along the reported ENU heading (north/east not swapped).
    h = end.heading_enu_rad
    assert math.hypot(end.vx_east_m_s - 6.0 * math.cos(h), end.vy_north_m_s - 6.0 * math.sin(h)) < 0.6


def test_offboard_loss_falls_back_to_rtl_after_com_of_loss_t(reference_mission):
    async def body(fleet):
        a = fleet.vehicle("a")
        await _airborne(a)
        await a.start_offboard(VelocityYawRateSetpoint(5.0, 0.0))
        # PX4's default COM_OBL_RC_ACT 0 without RC: Return.
        await a.wait_until(lambda s, p: s.mode is FlightMode.RETURN_TO_LAUNCH, WALL_S, "the offboard-loss failsafe")
        return a.sim.offboard_losses, a.sim.param("COM_OF_LOSS_T"), fleet.options.physics_dt_s, a.clock_s()
    losses, loss_t, dt, clock = _fly(reference_mission, body)
    assert len(losses) == 1
    silent = losses[0].failsafe_t_s - losses[0].last_setpoint_t_s
    assert loss_t < silent <= loss_t + dt + 1e-6  # one physics step after COM_OF_LOSS_T, in sim time
    assert clock - losses[0].failsafe_t_s <= 1.0 + dt + 1e-6  # the port saw RTL in the next 1 Hz heartbeat


@pytest.mark.parametrize("wire", [False, True], ids=["objects", "wire"])
def test_route_upload_download_round_trip_and_refusals(wire, reference_mission):
    mission = reference_mission
    plan = prepare(mission, None)

    async def body(fleet):
        a = fleet.vehicle("a")
        route = plan.waypoints(mission.vehicles[0])
        await a.upload_route(route, 30.0)
        stored = a.sim.missions.plan(0)
        back = await a.download_route()
        with pytest.raises(MissionUploadError, match="empty route"):
            await a.upload_route([], 30.0)
        with pytest.raises(MissionUploadError, match="mission upload: MAV_MISSION_"):
            await a.upload_route([GeoWaypoint(95.0, 8.0, 30.0)], 30.0)  # latitude out of range
        with pytest.raises(MissionUploadError, match="waypoint 1: .* cannot be encoded"):
            await a.upload_route([route[0], GeoWaypoint(47.4, math.nan, 30.0)], 30.0)
        return route, stored, back, await a.download_route()
    route, stored, back, after_refusal = _fly(mission, body, InProcessOptions(wire=wire))
    verify_readback("a", route, back)
    assert len(back) == len(route) and all(abs(b.lat_deg - r.lat_deg) < 1e-7 and abs(b.lon_deg - r.lon_deg) < 1e-7
                                           and b.alt_rel_m == r.alt_rel_m for b, r in zip(back, route))
    assert [it.param2 for it in stored] == [30.0] * len(route)  # the acceptance radius travels in param2
    assert after_refusal == back  # a refused upload leaves the stored plan as it was


def test_land_touches_down_and_auto_disarms(reference_mission):
    async def body(fleet):
        a = fleet.vehicle("a")
        await _airborne(a, 8.0)
        await a.land()
        await a.wait_until(lambda s, p: s.mode is FlightMode.LAND, WALL_S, "LAND in the next heartbeat")
        await a.wait_until(lambda s, p: s.landed is LandedState.ON_GROUND, WALL_S, "touchdown")
        await a.wait_until(lambda s, p: not s.armed, WALL_S, "auto-disarm")
        await a.wait_until(lambda s, p: s.mode is FlightMode.HOLD, WALL_S, "back to the mode before LAND")
        return a.latest_pose(), a.sim
    pose, sim = _fly(reference_mission, body)
    assert pose.alt_rel_m < 0.05 and not sim.in_air and not sim.armed


def test_one_clock_moves_both_vehicles_and_the_traffic():
    mission = load_mission(MOVING)
    moving = {o.id: o for o in mission.world.moving_obstacles}

    async def body(fleet):
        a, b = fleet.vehicle("a"), fleet.vehicle("b")
        await a.wait_until(lambda s, p: p is not None and p.t_sim_s >= 3.0, WALL_S, "3 s of sim time")
        return a.clock_s(), b.clock_s(), fleet.sim_time_s, dict(a.traffic()), dict(b.traffic())
    clock_a, clock_b, t, heard_a, heard_b = _fly(mission, body)
    assert clock_a == clock_b and abs(t - clock_a) < 0.06
    assert set(heard_a) == set(heard_b) == set(moving)
    for callsign, r in heard_a.items():
        o = moving[callsign]
        x, y = o.center_at(r.t_sim_s)
        vx, vy = o.motion.velocity_at(r.t_sim_s)
        assert math.hypot(r.x_east_m - x, r.y_north_m - y) < 0.5 and r.via == "a"
        assert math.hypot(r.vx_east_m_s - vx, r.vy_north_m_s - vy) < 0.05  # ADS-B course/speed -> ENU


def test_the_same_commands_fly_the_same_track_twice(reference_mission):
    async def body(fleet):
        a = fleet.vehicle("a")
        await _airborne(a)
        await a.start_offboard(VelocityYawRateSetpoint(8.0, -0.1))
        start = a.latest_pose().t_sim_s
        while (p := await a.next_pose(a.latest_pose().seq, WALL_S)).t_sim_s < start + 4.0:
            await a.send_setpoint(VelocityYawRateSetpoint(8.0, -0.1))
        return p.t_sim_s, p.x_east_m, p.y_north_m, p.heading_enu_rad
    mission = reference_mission
    assert _fly(mission, body) == _fly(mission, body)


def test_paced_never_runs_ahead_of_its_speed_factor(reference_mission):
    speedup = 20.0

    async def body(fleet):
        a = fleet.vehicle("a")
        t0 = fleet.sim_time_s  # the boot the fleet waits out is paced too
        await a.wait_until(lambda s, p: p is not None and p.t_sim_s >= t0 + 1.0, WALL_S, "1 s of sim time")
        return fleet.sim_time_s, time.monotonic()
    started = time.monotonic()
    sim_s, ended = _fly(reference_mission, body, InProcessOptions(speedup=speedup))
    wall_s = ended - started
    assert sim_s <= speedup * wall_s + 0.1  # a loaded machine only slows it down


@pytest.mark.parametrize("extra, message", [
    (["--connect", "a=udpin://0.0.0.0:1", "--connect", "b=udpin://0.0.0.0:2"], "cannot be combined with --connect"),
    (["--loss", "0.1"], "there is none with --in-process"),
    (["--speedup", "5000"], "--speedup: speedup 5000"),
])
def test_in_process_run_refuses_what_only_the_udp_path_has(extra, message, capsys):
    assert main(["run", str(REFERENCE), "--in-process", *extra]) == 2
    err = capsys.readouterr()
    assert message in err.err and len(err.err.strip().splitlines()) == 1 and err.out == ""
