"""The companion's geofence on real PX4: uploaded and read back, then enforced by PX4 itself when a
vehicle is flown out of it (by offboard setpoints from this test, on the vehicle's API link).

PX4 takes its own geofence action (GF_ACTION) and says so; the companion's own report of a PX4
fence event is not asserted here: this test pins what PX4 does.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from companion.sitl.px4 import API_PORT_BASE


ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"
SPEEDUP = 4.0  # PX4 SIH's speed factor in this tier: PX4 scales its loss timeouts with it

pytestmark = [pytest.mark.px4, pytest.mark.slow, pytest.mark.timeout(300)]

OFFBOARD_MAIN_MODE = 6  # PX4 custom main mode
VELOCITY_ONLY = 0b0000_1111_1100_0111  # SET_POSITION_TARGET_LOCAL_NED type_mask: velocity + yaw rate


class OffboardPilot:
    """A minimal offboard client on one vehicle's API link (blocking: this is a sync test)."""

    def __init__(self, port: int, system_id: int):
        self.link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=250, dialect="common")
        self.sysid = system_id
        if self.link.wait_heartbeat(timeout=15) is None:
            raise AssertionError(f"no heartbeat from PX4 on port {port}")
        self.acks: list[tuple[int, int]] = []

    def fly(self, seconds: float, north_m_s: float, east_m_s: float, down_m_s: float, *, every=None) -> None:
        """Stream a velocity setpoint for ``seconds`` of wall time; call ``every()`` each 0.5 s."""
        end, next_call = time.monotonic() + seconds, 0.0
        while time.monotonic() < end:
            self.link.mav.set_position_target_local_ned_send(
                0, self.sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY, 0, 0, 0,
                north_m_s, east_m_s, down_m_s, 0, 0, 0, 0, 0)
            if every is not None and time.monotonic() >= next_call:
                every()
                next_call = time.monotonic() + 0.5
            while (msg := self.link.recv_match(type="COMMAND_ACK", blocking=False)) is not None:
                self.acks.append((msg.command, msg.result))
            time.sleep(0.05)

    def command(self, command: int, *params: float) -> None:
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.link.mav.command_long_send(self.sysid, 1, command, 0, *p)

    def close(self) -> None:
        self.link.close()


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
    pilot = OffboardPilot(API_PORT_BASE, fleet.mission.vehicle("a").system_id)
    try:
        def offboard_and_arm() -> None:
            if fleet.modes("a")[-1] != "OFFBOARD":
                pilot.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                              OFFBOARD_MAIN_MODE)
            if not fleet.vehicle("a").armed:  # refused for PX4's first seconds: asked again
                pilot.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        pilot.fly(30.0 / SPEEDUP, 0.0, 0.0, -3.0, every=offboard_and_arm)  # climb in OFFBOARD
        assert fleet.vehicle("a").armed and fleet.modes("a")[-1] == "OFFBOARD", (fleet.modes("a"), pilot.acks)
        fleet.wait_until(lambda f: (f.vehicle("a").altitude_m or 0.0) > 10.0, timeout_s=30, what="a above 10 m")
        t_out = fleet.clock_s("a")
        pilot.fly(40.0 / SPEEDUP, 0.0, -8.0, 0.0)  # west, out of the fence, for 40 s of sim time
    finally:
        pilot.close()
    after = [m for t, m in fleet.vehicle("a").mode_history() if t > t_out]
    assert after and after[0] != "OFFBOARD", fleet.vehicle("a").mode_history()  # PX4 took over ...
    texts = [t for t in fleet.vehicle("a").statustext if "fence" in t.lower()]
    assert texts, fleet.vehicle("a").statustext  # ... and said why
    tr = fleet.track("a")
    assert tr.x_m.min() > -100.0 - 60.0, tr.x_m.min()  # stopped at the fence, not 320 m beyond it
    assert tr.x_m.min() < -30.0, tr.x_m.min()  # and it did fly out towards it
