"""The companion's geofence on real PX4: uploaded and read back, then enforced by PX4 itself when a
vehicle is flown out of it (by offboard setpoints from this test, on the vehicle's GCS link).

PX4 takes its own geofence action (GF_ACTION) and says so; the companion's own report of a PX4
fence event is not asserted here: this test pins what PX4 does.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from pymavlink.dialects.v20 import common as mavlink

from companion.testing.px4 import command_long


ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"
SPEEDUP = 4.0  # PX4 SIH's speed factor in this tier: PX4 scales its loss timeouts with it

pytestmark = [pytest.mark.px4, pytest.mark.slow, pytest.mark.timeout(300)]

OFFBOARD_MAIN_MODE = 6  # PX4 custom main mode
VELOCITY_ONLY = 0b0000_1111_1100_0111  # SET_POSITION_TARGET_LOCAL_NED type_mask: velocity + yaw rate


async def _offboard(fleet, name: str, seconds: float, north_m_s: float, east_m_s: float, down_m_s: float,
                    every: Callable[[], None] | None = None) -> None:
    """Stream a velocity setpoint to ``name`` on its GCS link for ``seconds`` of wall time (on the
    recorder's loop); call ``every()`` each 0.5 s."""
    sysid = fleet.mission.vehicle(name).system_id
    setpoint = mavlink.MAVLink_set_position_target_local_ned_message(
        0, sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY, 0, 0, 0, north_m_s, east_m_s, down_m_s, 0, 0, 0, 0, 0)
    end, next_call = time.monotonic() + seconds, 0.0
    while time.monotonic() < end:
        fleet.recorder.send(sysid, setpoint)
        if every is not None and time.monotonic() >= next_call:
            every()
            next_call = time.monotonic() + 0.5
        await asyncio.sleep(0.05)


def _solo(tmp_path: Path) -> Path:
    """The small reference with vehicle a alone: one PX4 is enough to judge its fence."""
    doc = yaml.safe_load(SMALL.read_text())
    doc["vehicles"] = doc["vehicles"][:1]
    out = tmp_path / "small_reference_a.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def test_the_fence_is_accepted_by_px4_and_px4_acts_on_a_breach(px4, companion, tmp_path):
    mission = _solo(tmp_path)
    fleet = px4(mission, speedup=SPEEDUP)
    upload = companion.cli("upload", mission, *fleet.connect_args(), timeout_s=180)
    assert upload.returncode == 0, upload.stdout[-3000:] + upload.stderr
    assert "a: geofence uploaded and read back (the area and 1 obstacle" in upload.stdout, upload.stdout

    # a stands at A (0, 0); the fence's inclusion polygon is the area plus 100 m (x >= -100 m).
    # This test flies it in OFFBOARD on its GCS link (the companion is gone; its API port is free).
    a = fleet.recorder.log(fleet.mission.vehicle("a").system_id)

    def offboard_and_arm() -> None:  # on the recorder's loop
        if a.last_mode != "OFFBOARD":
            fleet.recorder.send(a.system_id, command_long(a.system_id, mavlink.MAV_CMD_DO_SET_MODE,
                                                   mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN_MODE))
        if not a.armed:  # refused for PX4's first seconds: asked again
            fleet.recorder.send(a.system_id, command_long(a.system_id, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    fleet.telemetry.call(_offboard(fleet, "a", 40.0 / SPEEDUP, 0.0, 0.0, -2.0, every=offboard_and_arm), 60)
    assert a.armed and a.last_mode == "OFFBOARD", (a.modes, a.statustext)
    assert (a.altitude_m or 0.0) > 10.0, a.altitude_m
    t_out = fleet.clock_s("a")
    fleet.telemetry.call(_offboard(fleet, "a", 40.0 / SPEEDUP, 0.0, -8.0, 0.0), 60)  # west, for 40 s sim
    after = [m for t, m in fleet.vehicle("a").mode_history() if t > t_out]
    assert after and after[0] != "OFFBOARD", fleet.vehicle("a").mode_history()  # PX4 took over ...
    texts = [t for t in fleet.vehicle("a").statustext if "fence" in t.lower()]
    assert texts, fleet.vehicle("a").statustext  # ... and said why
    tr = fleet.track("a")
    assert tr.x_m.min() > -100.0 - 60.0, tr.x_m.min()  # stopped at the fence, not 320 m beyond it
    assert tr.x_m.min() < -30.0, tr.x_m.min()  # and it did fly out towards it
