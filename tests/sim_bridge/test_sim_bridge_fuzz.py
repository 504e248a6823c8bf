"""Robustness over real UDP: garbage on every port while an unmodified MAVSDK client flies on.

Random bytes, truncated and bit-flipped frames, hostile well-formed messages of every type, wrong
target ids, NaN parameters, out-of-order mission items and absurd mission counts go to each
vehicle's API socket and to the GCS socket. The stub must keep serving: the MAVSDK client stays
connected and healthy, commands still work, and the garbage is counted, not crashed on.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.testing import random_message, sim_connection_url, stub_on_free_ports

MISSION_YAML = """
name: fuzz
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
obstacles:
  - id: mover
    shape: circle
    center: [300, 700]
    radius_m: 30
    motion: {type: shuttle, to: [700, 700], speed_m_s: 4}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 5}
  - {name: b, start: B, goal: A, cruise_alt_m: 5}
"""


class Listener(asyncio.DatagramProtocol):
    """The fuzzer's own socket: whatever the stub answers is parsed and kept."""

    def __init__(self) -> None:
        self.parser = mavlink.MAVLink(None, 0, 0)
        self.parser.robust_parsing = True
        self.messages: list = []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport):
        self.transport = transport

    def datagram_received(self, data, addr):
        self.messages += [m for m in (self.parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]

    def acks(self, mission_result: int) -> int:
        return sum(1 for m in self.messages if m.get_type() == "MISSION_ACK" and m.type == mission_result)


def frame(msg, rng: random.Random) -> bytes:
    enc = mavlink.MAVLink(None, rng.randint(1, 255), rng.randint(0, 255))
    return msg.pack(enc)


def garbage(rng: random.Random) -> bytes:
    kind = rng.randrange(5)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 300)))
    try:
        buf = frame(random_message(rng), rng)
    except Exception:  # noqa: BLE001 - an unpackable random value: send noise instead
        return b"\xfd\xff"
    if kind == 1:
        return buf[: rng.randint(0, len(buf) - 1)]  # truncated
    if kind == 2:
        b = bytearray(buf)
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        return bytes(b)  # corrupted (CRC or header)
    if kind == 3:
        return b"\xfd" + bytes([rng.randrange(256)]) + bytes(rng.randrange(256) for _ in range(rng.randint(0, 20)))
    return buf  # well-formed, hostile values, often a wrong target


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_fuzzing_every_port_leaves_the_stub_serving_and_mavsdk_healthy():
    mission = parse_mission(MISSION_YAML, "fuzz.yaml")

    async def scenario():
        loop = asyncio.get_running_loop()
        rng = random.Random(20240611)
        async with stub_on_free_ports(mission, SimOptions(speedup=5.0)) as sim:
            va = sim.vehicle("a")
            async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
                await sdk.add_any_connection(sim_connection_url(sim, 0))
                system = await sdk.first_autopilot(timeout_s=10.0)
                assert system is not None
                tel, act = TelemetryAsync(system), ActionAsync(system)
                async with contextlib.aclosing(tel.subscribe_health_all_ok()) as health:
                    async with asyncio.timeout(15):
                        async for ok in health:
                            if ok:
                                break

                unhealthy: list[bool] = []

                async def watch_health():
                    async with contextlib.aclosing(tel.subscribe_health_all_ok()) as updates:
                        async for ok in updates:
                            if not ok:
                                unhealthy.append(ok)

                transport, fuzzer = await loop.create_datagram_endpoint(Listener, local_addr=("127.0.0.1", 0))
                targets = [sim.api_address(0), sim.api_address(1), sim.gcs_address]
                enc = mavlink.MAVLink(None, 77, 190)
                watcher = asyncio.create_task(watch_health())
                try:
                    def send(msg, dest):
                        transport.sendto(msg.pack(enc), dest)

                    for dest in targets:
                        # Wrong target ids must not arm anybody.
                        send(enc.command_long_encode(99, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0), dest)
                        # NaN parameter and NaN mode: rejected, nothing changes.
                        send(enc.param_set_encode(0, 1, b"MPC_XY_VEL_MAX", math.nan, mavlink.MAV_PARAM_TYPE_REAL32), dest)
                        send(enc.command_long_encode(0, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, *([math.nan] * 7)), dest)
                        # Absurd count, then an out-of-order item and a request for a missing one.
                        send(enc.mission_count_encode(0, 1, 65535, mavlink.MAV_MISSION_TYPE_MISSION), dest)
                        send(enc.mission_count_encode(0, 1, 3, mavlink.MAV_MISSION_TYPE_MISSION), dest)
                        send(enc.mission_item_int_encode(0, 1, 2, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 16, 0, 1,
                                                         0, 0, 0, 0, 473977420, 85455940, 10, 0), dest)
                        send(enc.mission_item_int_encode(0, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 1, 1, 1, 0), dest)
                        send(enc.mission_request_int_encode(0, 1, 400, 0), dest)
                    await asyncio.sleep(0.3)
                    assert not any(v.armed for v in sim.vehicles)
                    assert all(v.param("MPC_XY_VEL_MAX") == 12.0 for v in sim.vehicles)  # PX4's default, kept
                    # Bursts of 50 every 20 ms until the stub has read 3000 datagrams: under load
                    # the kernel drops what a descheduled stub's socket buffer cannot hold, so
                    # count what arrived rather than what was sent.
                    rx0 = sim.stats["rx_datagrams"]
                    for _ in range(600):
                        if sim.stats["rx_datagrams"] - rx0 >= 3000:
                            break
                        for _ in range(50):
                            transport.sendto(garbage(rng), rng.choice(targets))
                        await asyncio.sleep(0.02)
                    await asyncio.sleep(0.5)
                finally:
                    watcher.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await watcher
                    transport.close()

                assert unhealthy == [], "MAVSDK saw the vehicle unhealthy during the fuzz"
                assert await system.is_connected()
                # Still flying on command: a parameter round trip and fresh telemetry.
                await act.set_takeoff_altitude(7.0)
                assert va.param("MIS_TAKEOFF_ALT") == 7.0
                t = sim.sim_time_s
                async with contextlib.aclosing(tel.subscribe_position_velocity_ned()) as pos:
                    async with asyncio.timeout(5):
                        async for _ in pos:
                            if sim.sim_time_s > t + 0.5:
                                break

        # The absurd count and the out-of-order item got the right MISSION_ACK from each vehicle.
        for v in sim.vehicles:
            assert v.counters["wrong_target"] >= 1
            assert v.counters["handler_error"] == 0 and v.counters["step_error"] == 0
        assert fuzzer.acks(mavlink.MAV_MISSION_NO_SPACE) >= 3
        assert fuzzer.acks(mavlink.MAV_MISSION_INVALID_SEQUENCE) >= 3
        assert sim.stats["garbage"] > 100 and sim.stats["loop_errors"] == 0
        assert sim.stats["rx_datagrams"] >= 3000  # the garbage alone, as read by the stub

    asyncio.run(scenario())
