"""The .tlog is stamped in sim time, so log tools see the flight as flown, not as fast-forwarded."""

from __future__ import annotations

import asyncio

from pymavlink import mavutil

from sim_bridge.bridge import SimOptions
from sim_bridge.testing import stub_on_free_ports
from uav_model.mission import parse_mission

MISSION = parse_mission("""
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B}
  - {name: b, start: B, goal: A}
""", "tlog.yaml")


def _records(path) -> list[tuple[float, int, str]]:
    log = mavutil.mavlink_connection(str(path))
    out = []
    try:
        while (m := log.recv_match()) is not None:
            if m.get_type() != "BAD_DATA":
                out.append((m._timestamp, m.get_srcSystem(), m.get_type()))
    finally:
        log.close()
    return out


def test_tlog_spans_sim_time_and_splits_per_vehicle(tmp_path):
    async def fly() -> tuple[float, list]:
        opts = SimOptions(speedup=20.0, tlog_dir=tmp_path, tlog_per_vehicle=True)
        async with stub_on_free_ports(MISSION, opts, booted=False) as sim:  # the log spans from boot
            t0 = sim.sim_time_s
            while sim.sim_time_s - t0 < 30.0:
                await asyncio.sleep(0.05)
            return sim.sim_time_s - t0, sim.tlog_paths

    sim_elapsed, paths = asyncio.run(asyncio.wait_for(fly(), 30))
    combined, per_a, per_b = paths
    records = _records(combined)
    stamps = [t for t, src, _ in records if src == 1]
    span = stamps[-1] - stamps[0]
    # ~30 s of sim time went by in ~1.5 s of wall time: the log says 30, not 1.5.
    assert 0.8 * sim_elapsed < span <= sim_elapsed + 1.0
    assert {src for _, src, _ in records} >= {1, 2}
    assert {src for _, src, _ in _records(per_a)} == {1}
    assert {src for _, src, _ in _records(per_b)} == {2}
