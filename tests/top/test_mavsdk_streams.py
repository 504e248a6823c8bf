"""The MAVSDK adapter against a stub that streams at PX4's rates (ATTITUDE 100 Hz, GLOBAL_POSITION_INT
50 Hz of sim time) over real UDP: it asks for the rates it uses, and measures the speed factor."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.vehicle.mavsdk_open import open_mavsdk_vehicle
from companion.vehicle.mavsdk_vehicle import STREAM_RATE_HZ
from sim_bridge.bridge import SimOptions
from sim_bridge.testing import sim_connection_url, stub_on_free_ports
from uav_model.mission import load_mission

SMALL = Path(__file__).resolve().parents[2] / "missions" / "small_reference.yaml"
pytestmark = pytest.mark.timeout(120)
PUMPED = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)


def test_the_adapter_slows_px4_rate_streams_to_its_own_and_reads_the_speed_factor():
    mission = load_mission(SMALL)

    async def go():
        async with stub_on_free_ports(mission, SimOptions(speedup=4.0), gcs=False) as sim:
            stub = sim.vehicle(0)
            before = {m: stub.link_interval_s("api", m) for m in PUMPED}
            spec = mission.vehicles[0]
            async with open_mavsdk_vehicle(spec.name, spec.system_id, sim_connection_url(sim, 0), mission.origin,
                                           connect_timeout_s=10.0) as v:
                deadline = time.monotonic() + 30.0
                while time.monotonic() < deadline and (
                        v.sim_rate() is None or any(stub.link_interval_s("api", m) != 1 / STREAM_RATE_HZ
                                                    for m in PUMPED)):
                    await asyncio.sleep(0.1)
                after = {m: stub.link_interval_s("api", m) for m in PUMPED}
                return before, after, v.sim_rate()
    before, after, rate = asyncio.run(asyncio.wait_for(go(), 90.0))
    assert before == {mavlink.MAVLINK_MSG_ID_ATTITUDE: pytest.approx(0.01),
                      mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: pytest.approx(0.02)}
    assert after == {m: pytest.approx(1 / STREAM_RATE_HZ) for m in PUMPED}
    assert rate == pytest.approx(4.0, rel=0.2)


def test_each_position_keeps_its_own_time_stamp_when_attitude_comes_seldom():
    """MAVSDK's positions carry no time; the adapter reads each one's GLOBAL_POSITION_INT stamp
    through its link guard. With ATTITUDE slowed to one per 2 s of sim time, every position still
    becomes a pose sample at its own time, at the rate asked (``telemetry_hz``)."""
    mission = load_mission(SMALL)

    async def go():
        async with stub_on_free_ports(mission, SimOptions(speedup=4.0), gcs=False) as sim:
            stub = sim.vehicle(0)
            spec = mission.vehicles[0]
            async with open_mavsdk_vehicle(spec.name, spec.system_id, sim_connection_url(sim, 0), mission.origin,
                                           connect_timeout_s=10.0, telemetry_hz=5.0) as v:
                deadline = time.monotonic() + 30.0
                while time.monotonic() < deadline and any(stub.link_interval_s("api", m) != 0.2 for m in PUMPED):
                    await asyncio.sleep(0.1)
                asked = {m: stub.link_interval_s("api", m) for m in PUMPED}
                stub.tele.links["api"].set_interval(mavlink.MAVLINK_MSG_ID_ATTITUDE, 2.0)
                await asyncio.sleep(1.0)  # the attitudes already on their way
                times, seq = [], -1
                while len(times) < 40 and time.monotonic() < deadline + 30.0:
                    await v.wait_until(lambda st, p: p is not None and p.seq != seq, 5.0, "a pose")
                    pose = v.latest_pose()
                    seq = pose.seq
                    times.append(pose.t_sim_s)
                return asked, times
    asked, times = asyncio.run(asyncio.wait_for(go(), 100.0))
    assert asked == {m: pytest.approx(0.2) for m in PUMPED}  # the setting reached the autopilot
    gaps = [b - a for a, b in zip(times, times[1:])]
    # 5 Hz of sim time (a sample missed between two polls shows as one 0.4 s gap), never 2 s.
    assert len(times) == 40 and all(0.0 < g <= 0.45 for g in gaps), gaps
