"""Issue 12 over real UDP against the stub: what the companion refuses before anything arms, and
what it survives that PX4 does (../shared/px4-sih/README.md).

Small missions at 20x (tests/data/small_swap.yaml: the reference scaled by 0.2), so that each
flight takes seconds of wall time.
"""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.testing.relay import UplinkCut
from sim_bridge.testing import free_udp_port_block

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "tests" / "data" / "small_swap.yaml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _stub_has_param(name: str) -> bool:
    from companion.sitl.inprocess import InProcessFleet
    from uav_model.mission import load_mission
    fleet = InProcessFleet(load_mission(SMALL))
    return asyncio.run(fleet.vehicle("a").get_param(name)) is not None


# PX4's offboard-loss action and its timing (COM_OF_LOSS_T x the speed factor) come with the
# PX4-faithful stub (branch simcore); the stub before it always holds, after 1 s of sim time.
needs_px4_failsafe = pytest.mark.skipif(not _stub_has_param("COM_OBL_RC_ACT"),
                                        reason="the stub has no COM_OBL_RC_ACT (PX4-faithful stub not merged)")


def _swapped_back(tmp_path: Path) -> Path:
    """small_swap flown back: a from B to A, b from A to B (where the first flight left them)."""
    text = SMALL.read_text()
    text = text.replace("name: small_swap", "name: small_swap_back")
    a_to_b, b_to_a = "    start: A\n    goal: B", "    start: B\n    goal: A"
    text = text.replace(a_to_b, "@").replace(b_to_a, a_to_b).replace("@", b_to_a)
    ne, sw = "initial_heading_deg: 45.0", "initial_heading_deg: -135.0"
    text = text.replace(ne, "@").replace(sw, ne).replace("@", sw)
    path = tmp_path / "small_swap_back.yaml"
    path.write_text(text)
    return path


def _run(companion, mission: Path, stub, out: Path, *args: str, timeout_s: float = 120.0):
    """``companion run`` over --connect exactly as a user types it (no --shared-clock)."""
    return companion.cli("run", mission, *stub.connect_args(), "--out", out, *args, timeout_s=timeout_s)


def _nothing_armed(stub) -> None:
    for v in stub.mission.vehicles:
        assert not any(stub.vehicle(v.name).armed_history), v.name


def _foreign_stub(mission: Path, port_base: int, tmp_path: Path) -> subprocess.Popen:
    """A second sim-bridge sending to ``port_base``: another autopilot already on the companion's port."""
    log = open(tmp_path / f"foreign_{port_base}.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(mission), "--speedup", "20", "--no-gcs",
                             "--api-port-base", str(port_base)], stdout=log, stderr=subprocess.STDOUT)
    log.close()
    path = tmp_path / f"foreign_{port_base}.log"
    deadline = time.monotonic() + 20.0
    while b"running at" not in path.read_bytes():  # then it streams (it needs no answer to send)
        assert proc.poll() is None and time.monotonic() < deadline, path.read_text()
        time.sleep(0.1)
    return proc


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)


def test_a_vehicle_away_from_its_station_is_refused_and_nothing_arms(sitl, companion, tmp_path):
    stub = sitl(SMALL, speedup=20)
    moved = tmp_path / "moved.yaml"  # the mission puts A 300 m east of where vehicle a stands
    moved.write_text(SMALL.read_text().replace("  A: [0.0, 0.0]", "  A: [300.0, 0.0]"))
    result = _run(companion, moved, stub, tmp_path / "out")
    assert result.returncode == 2, result.stdout + result.stderr
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and "300 m from station A" in err[0] and "--plan-from-current" in err[0], err
    assert "nothing was armed" in err[0]
    time.sleep(0.5)  # a stray arm would show on the GCS link by now
    _nothing_armed(stub)


def test_plan_from_current_flies_from_where_the_vehicle_is(sitl, companion, tmp_path):
    stub = sitl(SMALL, speedup=20)
    moved = tmp_path / "moved.yaml"
    moved.write_text(SMALL.read_text().replace("  A: [0.0, 0.0]", "  A: [300.0, 0.0]"))
    result = _run(companion, moved, stub, tmp_path / "out", "--plan-from-current")
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    assert "planning from (0, 0) m, 300 m from station A" in result.stdout
    track = stub.track("a", since_mode="OFFBOARD")
    assert abs(track.x_m[0]) < 20.0 and abs(track.y_m[0]) < 20.0  # it left from where it stood
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["success"] and summary["vehicles"]["b"]["arrived"]  # b's goal is the moved A
    assert stub.track("b").x_m[-1] == pytest.approx(300.0, abs=25.0)


def test_a_second_autopilot_on_the_port_is_refused_and_nothing_arms(sitl, companion, tmp_path):
    stub = sitl(SMALL, speedup=20)
    foreign = _foreign_stub(SMALL, stub.api_port_base, tmp_path)  # also system 1 -> port base
    try:
        result = _run(companion, SMALL, stub, tmp_path / "out", timeout_s=60)
    finally:
        _stop(foreign)
    assert result.returncode == 2, result.stdout + result.stderr
    err = result.stderr.strip()
    assert "2 autopilots answer as system 1" in err and str(stub.api_port_base) in err, err  # a comes first
    _nothing_armed(stub)


def test_the_embedded_stub_refuses_a_port_another_autopilot_sends_to(companion, tmp_path):
    base = free_udp_port_block(2)
    foreign = _foreign_stub(SMALL, base, tmp_path)
    try:
        result = companion.cli("run", SMALL, "--speedup", "20", "--port-base", base, "--no-land",
                               "--out", tmp_path / "out", timeout_s=60)
    finally:
        _stop(foreign)
    assert result.returncode == 2, result.stdout + result.stderr
    err = result.stderr.strip()
    assert f"UDP port {base}: another autopilot is already sending to it (system 1" in err, err
    assert "--port-base" in err and "starting the embedded sim_bridge" not in result.stdout


def test_two_runs_in_a_row_against_one_stub(sitl, companion, tmp_path):
    # After the first flight both vehicles sit landed at the other station; PX4 (and the stub) then
    # go back to the mode before LAND, so the second run (the way back) arms them again directly
    # (from LAND it would switch to HOLD first, as PX4 users do).
    stub = sitl(SMALL, speedup=20)
    first = _run(companion, SMALL, stub, tmp_path / "first")
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr
    second = _run(companion, _swapped_back(tmp_path), stub, tmp_path / "second")
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr
    assert "Arming denied" not in second.stdout and "refused" not in second.stdout
    for name in ("a", "b"):
        assert stub.vehicle(name).armed_history.count(True) >= 2
        # PX4's COM_DISARM_PRFLT (10 s) stays at its default and never beat a take-off.
        assert not [t for t in stub.vehicle(name).statustext if "preflight disarming" in t], name


def _udp_bound(port: int) -> bool:
    """Some process (in this network namespace) has a UDP socket bound to ``port``."""
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        if any(int(row.split()[1].rsplit(":", 1)[1], 16) == port for row in rows):
            return True
    return False


def test_a_companion_listening_before_the_autopilot_boots_flies(companion, tmp_path):
    # PX4 reports no sensors for its first seconds and refuses to arm (TEMPORARILY_REJECTED,
    # MAVSDK: COMMAND_DENIED) until ~4.2 s of sim time after boot. Here the companion listens
    # first and the stub boots after it, with PX4's defaults, so the companion hears it from its
    # first datagram: it waits for the health, retries an arm that came too early, and flies.
    # (At 20x the boot is 0.2 s of wall time, mostly over during the companion's 0.6 s link
    # probe, so the arm is rarely early here; tests/top/test_inprocess_px4_start.py flies from
    # the stub's first step.)
    base = free_udp_port_block(2)
    live = companion.start(SMALL, "--connect", f"a=udpin://127.0.0.1:{base}",
                           "--connect", f"b=udpin://127.0.0.1:{base + 1}", speedup=20)
    deadline = time.monotonic() + 60.0  # a's port is open before the autopilot's first datagram (b's opens next)
    while not _udp_bound(base):
        assert time.monotonic() < deadline and live.process.poll() is None, "the companion never listened"
        time.sleep(0.05)
    log_path = tmp_path / "booting_stub.log"
    with open(log_path, "wb") as log:
        stub = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(SMALL), "--speedup", "20", "--no-gcs",
                                 "--api-port-base", str(base)], stdout=log, stderr=subprocess.STDOUT)
    try:
        run = live.wait(150)
    finally:
        _stop(stub)
    assert run.exit_code == 0, run.tail
    assert run.summary["success"], run.summary["reason"]
    for name in ("a", "b"):
        refused = f"{name}: arm refused" in run.stdout
        assert not refused or f"{name}: armed after" in run.stdout, run.stdout[-3000:]


def _open_field(tmp_path: Path) -> Path:
    """small_swap's vehicles on two parallel lanes 636 m apart, northward along the area's west and
    east edges, without the fire zone: where PX4's Return (a U-turn of 60 m on this plant, then a
    straight line home) can neither hit what only the companion knows about nor bring the two
    together, whenever the loss comes."""
    text = SMALL.read_text()
    start, end = text.index("stations:\n"), text.index("vehicles:\n")
    text = text[:start] + ("stations:\n  A: [0.0, 0.0]\n  B: [0.0, 636.4]\n  C: [636.4, 0.0]\n"
                           "  D: [636.4, 636.4]\nobstacles: []\n") + text[end:]
    text = text.replace("    start: B\n    goal: A\n", "    start: C\n    goal: D\n")
    text = re.sub(r"initial_heading_deg: -?[0-9.]+", "initial_heading_deg: 90.0", text)
    path = tmp_path / "small_open_field.yaml"
    path.write_text(text)
    return path


def _fly_with_uplink_cut(sitl, companion, *args: str, cut_after_s: float, cut_s: float, mission: Path = SMALL):
    """Fly ``mission`` through an UplinkCut relay; cut both uplinks ``cut_after_s`` sim seconds
    after departure for ``cut_s`` seconds of wall time. Returns (stub, run)."""
    stub = sitl(mission, speedup=20)  # PX4's defaults: COM_OBL_RC_ACT 0 (offboard loss -> Return)
    companion_base = free_udp_port_block(2)
    relay = UplinkCut([stub.api_port_base, stub.api_port_base + 1], [companion_base, companion_base + 1])
    try:
        live = companion.start(mission, "--connect", f"a=udpin://127.0.0.1:{companion_base}",
                               "--connect", f"b=udpin://127.0.0.1:{companion_base + 1}", *args, speedup=20)
        for name in ("a", "b"):
            stub.wait_for_mode(name, "OFFBOARD", timeout_s=90)
        t_depart = max(stub.mode_times(name, "OFFBOARD")[0] for name in ("a", "b"))
        stub.wait_for_clock(t_depart + cut_after_s, timeout_s=60)
        relay.cut(cut_s)
        run = live.wait(150)
    finally:
        relay.close()
    return stub, run


def _failsafe_then_offboard(stub, failsafe_mode: str) -> None:
    for name in ("a", "b"):
        modes = stub.modes(name)
        i = modes.index("OFFBOARD")
        assert failsafe_mode in modes[i:], modes  # the failsafe happened ...
        j = modes.index(failsafe_mode, i)
        assert "OFFBOARD" in modes[j:], modes  # ... and OFFBOARD came back
        assert any("Failsafe activated" in t for t in stub.vehicle(name).statustext)


@needs_px4_failsafe
def test_px4_default_failsafe_and_a_3_s_uplink_blackout_the_mission_succeeds(sitl, companion):
    # The stub boots with PX4's default COM_OBL_RC_ACT 0 (offboard loss -> Return), as in
    # companion-runs/px4_1x_uplinkdrop, where the companion stood down and the mission failed.
    # The companion sets 5 (Hold) at connect: a Return flies straight home across the fire zone.
    # Both uplinks are cut for 3 s of wall time mid-flight; the loss timeout (COM_OF_LOSS_T x
    # the speed factor, ~1 s wall) runs out, the vehicles hold, and OFFBOARD resumes.
    stub, run = _fly_with_uplink_cut(sitl, companion, cut_after_s=20.0, cut_s=3.0)
    assert run.exit_code == 0, run.tail
    assert run.summary["success"], run.summary["reason"]
    assert "COM_OBL_RC_ACT 0 (Position mode (without RC: Return)) -> 5 (Hold)" in run.stdout
    log = (run.out_dir / "companion.log").read_text()
    assert "Wrong type in param set" not in log and "rejected" not in log  # set as the INT32 it is, first time
    _failsafe_then_offboard(stub, "HOLD")
    assert "fell back to HOLD (offboard loss)" in run.stdout, run.stdout[-3000:]
    assert "stands down" not in run.stdout
    # The run succeeded, and says what it came back from: each vehicle's Hold, recovered.
    listed = {(f["vehicle"], f["mode"], f["cause"], f["recovered"]) for f in run.summary["failsafes"]}
    assert listed == {("a", "HOLD", "offboard_loss", True), ("b", "HOLD", "offboard_loss", True)}, run.summary["failsafes"]
    assert all(f["t_mission_s"] > 15.0 for f in run.summary["failsafes"])
    assert "failsafe: a entered HOLD at" in run.stdout and ", recovered)" in run.stdout


@needs_px4_failsafe
def test_kept_rtl_failsafe_is_resumed_not_stood_down(sitl, companion, tmp_path):
    # --keep-failsafe leaves PX4's default: the vehicles go to RTL after the loss; the companion
    # treats that as an offboard loss (not an operator's override), keeps streaming, and the
    # vehicles are back in OFFBOARD. Over open ground, on lanes far apart: a Return turns home (a
    # U-turn of 60 m on this plant) and flies straight there, through any obstacle only the
    # companion knows about; on small_swap, how far it got depended on the machine's load, and it
    # once clipped the fire zone (the hazard for which the companion sets Hold by default, tested
    # above); head-on without it, or on lanes 141 m apart, the Returns' U-turns lost separation.
    stub, run = _fly_with_uplink_cut(sitl, companion, "--keep-failsafe", cut_after_s=30.0, cut_s=1.5,
                                     mission=_open_field(tmp_path))
    assert run.exit_code == 0, run.tail
    assert run.summary["success"], run.summary["reason"]
    _failsafe_then_offboard(stub, "RTL")
    assert "fell back to RTL (offboard loss)" in run.stdout, run.stdout[-3000:]
    assert "stands down" not in run.stdout


def test_an_operator_switching_to_hold_is_obeyed_not_resumed(sitl, companion):
    # A pilot on the vehicle's link switches a to Hold mid-flight: no "Failsafe activated", no gap
    # in our telemetry. That is an override: the companion stands down (after its 2 s grace for a
    # late failsafe text) and does not put a back into OFFBOARD.
    stub = sitl(SMALL, speedup=20)
    live = companion.start(stub)
    stub.wait_for_mode("a", "OFFBOARD", timeout_s=90)
    stub.wait_for_clock(stub.mode_times("a", "OFFBOARD")[0] + 15.0, timeout_s=60)
    hold = stub.telemetry.call(stub.recorder.command_via_tap(
        stub.mission.vehicle("a").system_id, mavlink.MAV_CMD_DO_SET_MODE,
        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3))  # PX4 AUTO.LOITER: Hold
    assert hold == mavlink.MAV_RESULT_ACCEPTED
    run = live.wait(120)
    assert run.exit_code != 0, (stub.modes("a"), stub.vehicle("a").statustext, run.tail)
    assert "mode changed to HOLD by someone else (no failsafe)" in run.stdout, run.stdout[-3000:]
    assert "fell back to HOLD" not in run.stdout
    modes = stub.modes("a")
    assert "OFFBOARD" not in modes[modes.index("HOLD", modes.index("OFFBOARD")):], modes
    assert not [t for t in stub.vehicle("a").statustext if "Failsafe activated" in t]
