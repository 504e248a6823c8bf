"""Injected link faults (loss, latency, blackouts) and the .tlog recording, over real UDP."""

from __future__ import annotations

import asyncio
import contextlib
import socket

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.faults import Blackout, FaultConfig
from sim_bridge.vehicle.px4 import FlightMode as StubMode
from sim_bridge.testing import sim_connection_url, stub_on_free_ports

MISSION_YAML = """
name: faults
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 5}
  - {name: b, start: B, goal: A, cruise_alt_m: 5}
"""


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "faults.yaml")


@contextlib.asynccontextmanager
async def client(url: str):
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(url)
        system = await sdk.first_autopilot(timeout_s=10.0)
        assert system is not None
        yield system


async def first(agen, pred=bool, timeout_s: float = 15.0):
    async with contextlib.aclosing(agen):
        async with asyncio.timeout(timeout_s):
            async for item in agen:
                if pred(item):
                    return item


@pytest.mark.timeout(60)
def test_tlog_records_the_gcs_stream_both_ways_readable_by_pymavlink(mission, tmp_path):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0, tlog_dir=tmp_path), booted=False) as sim:
            path = sim.tlog_path
            gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                enc = mavlink.MAVLink(None, 250, 190)
                gcs.sendto(enc.command_long_encode(2, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                   mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0).pack(enc),
                           sim.gcs_address)
                await asyncio.sleep(1.5)
            finally:
                gcs.close()
            sim_t = sim.sim_time_s
        return path, sim_t

    path, sim_t = asyncio.run(scenario())
    assert path is not None and path.parent == tmp_path and path.suffix == ".tlog"
    log = mavutil.mavlink_connection(str(path))
    seen: dict[tuple[int, str], int] = {}
    stamps = []
    try:
        while (m := log.recv_match()) is not None:
            if m.get_type() == "BAD_DATA":
                raise AssertionError(f"unreadable record in {path}")
            key = (m.get_srcSystem(), m.get_type())
            seen[key] = seen.get(key, 0) + 1
            stamps.append(m._timestamp)  # noqa: SLF001 - pymavlink's record timestamp
    finally:
        log.close()
    assert stamps == sorted(stamps) and stamps[-1] - stamps[0] < 10.0
    for sysid in (1, 2):
        assert seen[(sysid, "HEARTBEAT")] >= 2
        assert seen[(sysid, "GLOBAL_POSITION_INT")] >= 5
    assert seen[(250, "COMMAND_LONG")] == 1  # what the GCS sent is recorded too
    assert seen[(2, "AUTOPILOT_VERSION")] == 1 and seen[(2, "COMMAND_ACK")] == 1
    assert sim_t > 5.0


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_mavsdk_flies_through_packet_loss_and_latency(mission):
    async def scenario():
        faults = FaultConfig(loss_p=0.2, latency_ms=40.0)
        async with stub_on_free_ports(mission, SimOptions(speedup=4.0, faults=faults, seed=3)) as sim:
            async with client(sim_connection_url(sim, 0)) as system:
                tel, act = TelemetryAsync(system), ActionAsync(system)
                await first(tel.subscribe_health_all_ok())
                await act.arm()  # MAVSDK retries what the link loses
                await act.takeoff()
                await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD and sim.vehicle(0).in_air, 30.0)
                counts = sim.fault_counts()
                out_total = counts["a/api/out/dropped"] + counts["a/api/out/passed"]
                assert out_total > 200 and counts["a/api/out/dropped"] / out_total == pytest.approx(0.2, abs=0.05)
                assert counts["a/api/in/dropped"] + counts["a/api/in/passed"] > 0  # the uplink is faulted too
                assert "a/gcs/out/dropped" not in counts  # faults are on the API links only
                assert sim.vehicle(0).position_enu_m[2] == pytest.approx(2.5, abs=0.3)  # PX4's MIS_TAKEOFF_ALT

    asyncio.run(scenario())


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_scheduled_blackout_disconnects_mavsdk_and_the_link_comes_back(mission):
    async def scenario():
        blackout = Blackout(start_s=4.0, duration_s=8.0)  # sim seconds: 2 s .. 6 s of wall time at 2x
        async with stub_on_free_ports(mission, SimOptions(speedup=2.0, faults=FaultConfig(blackouts=(blackout,))),
                                      booted=False) as sim:
            async with client(sim_connection_url(sim, 1)) as system:
                states = system.is_connected_state()
                async with contextlib.aclosing(states):
                    async with asyncio.timeout(20):
                        async for connected in states:
                            if not connected:
                                lost_at = sim.sim_time_s
                                break
                    assert blackout.start_s < lost_at < blackout.start_s + blackout.duration_s
                    async with asyncio.timeout(20):
                        async for connected in states:
                            if connected:
                                back_at = sim.sim_time_s
                                break
                    assert back_at >= blackout.start_s + blackout.duration_s
                assert sim.fault_counts()["b/api/out/dropped"] > 10
                assert sim.fault_counts()["a/api/out/dropped"] > 10  # a configured blackout cuts every API link

    asyncio.run(scenario())


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_runtime_blackout_of_one_vehicle_fails_it_safe_and_spares_the_other(mission):
    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0)) as sim:
            va = sim.vehicle("a")
            async with client(sim_connection_url(sim, 0)) as system:
                tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
                await first(tel.subscribe_health_all_ok())
                await act.arm()
                await act.takeoff()
                await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD and va.in_air, 30.0)
                await off.set_velocity_body(VelocityBodyYawspeed(4.0, 0.0, 0.0, 0.0))
                await off.start()
                assert await sim.wait_for(lambda: va.mode is StubMode.OFFBOARD, 3.0)
                # COM_OF_LOSS_T (1 s) times the speed factor: 5 s of sim time without a setpoint.
                sim.blackout(8.0, "a")
                assert await sim.wait_for(lambda: va.mode is StubMode.RTL, 5.0)
                (loss,) = va.offboard_losses
                timeout = va.param("COM_OF_LOSS_T") * sim.options.speedup
                assert loss.failsafe_t_s - loss.last_setpoint_t_s <= timeout + sim.options.physics_dt_s + 1e-9
                # The link returns and MAVSDK's setpoints with it: PX4 re-enters OFFBOARD by itself.
                assert await sim.wait_for(lambda: va.mode is StubMode.OFFBOARD, 5.0)
                assert sim.fault_counts()["a/api/out/dropped"] > 0
            assert "b/api/out/dropped" not in sim.fault_counts() or sim.fault_counts()["b/api/out/dropped"] == 0

    asyncio.run(scenario())
