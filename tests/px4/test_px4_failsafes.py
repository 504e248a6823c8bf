"""What PX4 does when the link or the companion fails, and the companion's fence on PX4, judged by
what a GCS hears on PX4's port 14550 (the ``px4`` fixture's recorder)."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

from companion.testing.relay import UplinkCut
from companion.sitl.px4 import API_PORT_BASE


ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"
SPEEDUP = 4.0  # PX4 SIH's speed factor in this tier: PX4 scales its loss timeouts with it

pytestmark = [pytest.mark.px4, pytest.mark.slow, pytest.mark.timeout(300)]

RELAY_PORT_BASE = API_PORT_BASE + 100  # where the companion listens behind the relay
# The occlusion certificate (pre-flight numpy, 20 CPU s by default) is not read here: skipped to keep the tier short.
NO_CERTIFICATE = "--no-certificate"


def _departed(fleet, after_s: float) -> None:
    """Until both vehicles have flown ``after_s`` sim seconds in OFFBOARD."""
    for name in ("a", "b"):
        fleet.wait_for_mode(name, "OFFBOARD", timeout_s=180)
    t_depart = max(fleet.mode_times(name, "OFFBOARD")[0] for name in ("a", "b"))
    fleet.wait_for_clock(t_depart + after_s, timeout_s=60)


def test_a_3_s_uplink_blackout_on_px4_defaults_the_mission_goes_on(px4, companion):
    # PX4 boots with its defaults (COM_OBL_RC_ACT 0: offboard loss -> Return); the companion sets
    # 5 (Hold) at connect. Both uplinks are cut for 3 s of wall time, longer than the loss timeout
    # (COM_OF_LOSS_T x the speed factor, ~1 s of wall time): PX4 fails safe to Hold, re-enters
    # OFFBOARD when the setpoints come back, and the mission succeeds.
    fleet = px4(SMALL, speedup=SPEEDUP)
    relay = UplinkCut([API_PORT_BASE, API_PORT_BASE + 1], [RELAY_PORT_BASE, RELAY_PORT_BASE + 1])
    try:
        fleet.listen_port_base = RELAY_PORT_BASE
        live = companion.start(fleet, NO_CERTIFICATE)
        _departed(fleet, 20.0)
        relay.cut(3.0)
        run = live.wait(240)
    finally:
        relay.close()
    assert run.exit_code == 0, run.tail
    assert run.summary["success"], run.summary["reason"]
    assert "-> 5 (Hold)" in run.stdout, run.stdout[-3000:]
    for name in ("a", "b"):
        modes = fleet.modes(name)
        i = modes.index("OFFBOARD")
        assert "HOLD" in modes[i:], modes  # the failsafe happened ...
        assert "OFFBOARD" in modes[modes.index("HOLD", i):], modes  # ... and OFFBOARD came back
        assert any("Failsafe activated" in t for t in fleet.vehicle(name).statustext), fleet.vehicle(name).statustext
    assert "stands down" not in run.stdout


def test_a_killed_companion_leaves_px4_holding_within_its_loss_timeout(px4, companion):
    fleet = px4(SMALL, speedup=SPEEDUP)
    live = companion.start(fleet, NO_CERTIFICATE)
    _departed(fleet, 10.0)
    killed_wall_s = time.monotonic()
    live.signal(signal.SIGKILL)  # the whole process group, MAVSDK servers too: a crash
    for name in ("a", "b"):
        fleet.wait_for_mode(name, "HOLD", timeout_s=30)  # the companion set COM_OBL_RC_ACT 5 (Hold)
        t_kill = fleet.vehicle(name).sim_time_at(killed_wall_s)
        t_hold = fleet.mode_times(name, "HOLD")[-1]
        # The last setpoint left at most a keep-alive before the kill; PX4 reports its mode in a
        # 1 Hz (sim) heartbeat on the GCS link, so allow one heartbeat and 0.5 s of wall lag.
        loss_s = fleet.loss_timeout_s(name)
        assert 0.0 < t_hold - t_kill <= loss_s + 1.0 + 0.5 * SPEEDUP, (name, t_hold - t_kill, loss_s)
        assert fleet.vehicle(name).armed
        assert any("Failsafe activated" in t for t in fleet.vehicle(name).statustext)
    t_settled = max(fleet.mode_times(n, "HOLD")[-1] for n in ("a", "b")) + 5.0
    fleet.wait_for_clock(t_settled + 10.0)
    for name in ("a", "b"):
        assert fleet.modes(name)[-1] == "HOLD"
        tr = fleet.track(name)
        after = tr.t_s >= t_settled
        moved = np.hypot(np.ptp(tr.x_m[after]), np.ptp(tr.y_m[after]))
        assert moved < 5.0, (name, moved)  # it holds its position (PX4's Hold wandered 2.3 m in 10 s)
    assert not live.survivors()
