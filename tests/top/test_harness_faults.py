"""SPEC §6 faults, judged by the vehicles' telemetry: a lossy, late link; a link blackout; a
position-telemetry freeze; a companion crash; bad mission files.

Only the loss test flies a whole mission (a small one). The others fly long enough to see the fault and
what follows, at a lower speed factor where the GCS link samples finely enough to time it.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
SMALL = ROOT / "tests" / "data" / "small_swap.yaml"
# One bad file per stage that refuses it (YAML, schema, geometry, reachability): each is a companion
# process against a live stub. tests/top/test_companion_cli.py runs every bad file through `run`.
BAD_MISSIONS = [ROOT / "tests" / "data" / "bad_missions" / f"{name}.yaml"
                for name in ("yaml_syntax", "unknown_key", "station_in_obstacle", "unreachable_goal")]

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _moved_m(track, t0: float, t1: float) -> float:
    """Straight-line distance covered between two sim times (positions interpolated)."""
    x, y = track.at(np.array([t0, t1]))
    return float(np.hypot(x[1] - x[0], y[1] - y[0]))


def _depart(stub, flown_s: float) -> float:
    """Wait until both vehicles are in OFFBOARD and have flown ``flown_s`` sim seconds; the departure time."""
    for name in ("a", "b"):
        stub.wait_for_mode(name, "OFFBOARD", timeout_s=60)
    t_depart = max(stub.mode_times(name, "OFFBOARD")[0] for name in ("a", "b"))
    stub.wait_for_clock(t_depart + flown_s, timeout_s=60)
    return t_depart


def test_five_percent_loss_and_100_ms_latency(sitl, companion):
    # The small swap (the reference scaled by 0.2): the faults act per message, not per metre, and
    # the reference flown whole (tests/top/test_harness_scenarios.py) took five times the wall time.
    stub = sitl(SMALL, speedup=20, loss=0.05, latency_ms=100, seed=7)
    run = companion(stub)
    assert run.exit_code == 0, run.tail
    stub.assert_success()  # 100 ms of latency is 2 s of sim time at 20x


def test_link_blackout_mid_flight_holds_then_resumes(companion):
    # 15 s (sim) of silence on both API links, mid-flight, on the companion's embedded stub: no
    # setpoint reaches the vehicles, so after COM_OF_LOSS_T (1 s, times the speed factor: 10 s of
    # sim time at 10x) they fail safe to HOLD (COM_OBL_RC_ACT 5, set by the companion); when the link
    # is back OFFBOARD resumes (PX4 re-enters it by itself when setpoints come again).
    start_s, duration_s = 150.0, 15.0  # departure ~80-130 s at 10x (pre-flight checks take a few s)
    live = companion.start(REFERENCE, "--blackout", f"{start_s:g}:{duration_s:g}", speedup=10)
    stub = live.telemetry
    _depart(stub, 0.0)
    assert max(stub.mode_times(n, "OFFBOARD")[0] for n in ("a", "b")) < start_s - 10, "departed too late"
    stub.wait_for_clock(start_s + duration_s + 30.0, timeout_s=60)
    live.signal(signal.SIGTERM)
    run = live.wait(30)
    assert run.exit_code == 1 and run.summary["reason"] == "interrupted", run.tail

    for name in ("a", "b"):
        stub.assert_modes_in_order(name, "OFFBOARD", "HOLD", "OFFBOARD")
        holds = [t for t in stub.mode_times(name, "HOLD") if t > start_s - 1]
        resumed = [t for t in stub.mode_times(name, "OFFBOARD") if t > start_s]
        # The autopilot's failsafe: 10 s after the last setpoint that got through, which may
        # predate the blackout by a keep-alive gap, and mode times are stamped to the nearest
        # position sample (0.2 s): so not before start + 9.5 s, and within the blackout.
        assert start_s + 9.5 <= holds[0] <= start_s + duration_s, (name, holds)
        assert start_s + duration_s <= resumed[0] <= start_s + duration_s + 5.0, (name, resumed)
        track = stub.track(name)
        assert _moved_m(track, resumed[0] + 5.0, resumed[0] + 25.0) > 150.0  # flying again at ~10 m/s
    stub.assert_clearance()
    stub.assert_separation()
    stub.assert_geofence()

    # The companion never planned on data from the silence; it logged the stale telemetry.
    rows = run.flight_log()
    for name in ("a", "b"):
        stale = [r for r in rows if r["vehicle"] == name and r["note"].startswith("stale")]
        assert stale and all(r["action"] == "hover" for r in stale)
        flown = [float(r["t_sim_s"]) for r in rows if r["vehicle"] == name and r["action"] == "fly"]
        # (time_boot_ms truncates: the first sample after the silence may read a millisecond early)
        assert not any(start_s < t < start_s + duration_s - 0.02 for t in flown), name
    assert not live.survivors(), "the embedded stub or a MAVSDK server outlived the companion"


def test_position_freeze_hovers_the_vehicle_then_it_flies_on(sitl, companion):
    # Vehicle a's position streams stop on its API link while its heartbeat and clock go on
    # (SPEC §6 "telemetry stall"): the companion must hover it, never fly it on old data.
    stub = sitl(REFERENCE, speedup=10)
    live = companion.start(stub)
    _depart(stub, 20.0)
    stub.freeze_position("a")
    t_freeze = stub.clock_s("a")  # the GCS clock lags the vehicle a little: this is not later than the freeze
    stub.wait_for_clock(t_freeze + 7.0, "a")
    stub.resume_position("a")
    t_resume = stub.clock_s("a")
    stub.wait_for_clock(t_resume + 25.0)

    a, b = stub.track("a"), stub.track("b")
    # Stale after safety.telemetry_timeout_s (1 s), then braking from 10 m/s at 8 m/s^2 (~1.3 s).
    assert _moved_m(a, t_freeze + 3.5, t_freeze + 7.0) < 2.0, "a kept flying without position telemetry"
    assert _moved_m(b, t_freeze + 3.5, t_freeze + 7.0) > 25.0, "b should not have been held"
    assert _moved_m(a, t_resume + 5.0, t_resume + 20.0) > 100.0, "a did not fly on after the freeze"
    # Setpoints kept coming (hover): no offboard-loss failsafe.
    assert stub.modes("a")[-1] == "OFFBOARD" and not [t for t in stub.mode_times("a", "HOLD") if t > t_freeze], \
        stub.vehicle("a").mode_history()
    stub.assert_clearance()
    stub.assert_separation()
    assert live.process.poll() is None, "the companion gave up"


def test_killed_companion_leaves_both_vehicles_holding(sitl, companion):
    # 5x: the GCS link then stamps the mode change to a few hundredths of a second of sim time.
    stub = sitl(REFERENCE, speedup=5)
    live = companion.start(stub)
    _depart(stub, 10.0)
    killed_wall_s = time.monotonic()
    live.signal(signal.SIGKILL)  # the whole process group, MAVSDK servers too: a crash
    loss_s = 1.0 * 5  # COM_OF_LOSS_T (1 s), times the speed factor as PX4 SITL does
    for name in ("a", "b"):
        stub.wait_for_mode(name, "HOLD", timeout_s=10)
        t_kill = stub.vehicle(name).sim_time_at(killed_wall_s)
        t_hold = stub.mode_times(name, "HOLD")[-1]
        # The last setpoint went out at most one keep-alive (0.1 s) before the kill; the loss timer
        # now runs about one second of wall time, so allow the stub's loop 0.4 s of wall lag (2 s sim).
        assert 0.0 < t_hold - t_kill <= loss_s + 0.2 + 0.4 * 5, (name, t_hold - t_kill)
        assert stub.vehicle(name).armed
        assert any("Failsafe activated" in text for text in stub.vehicle(name).statustext)
    stub.wait_for_clock(stub.clock_s("a") + 10.0)
    for name in ("a", "b"):
        assert stub.modes(name)[-1] == "HOLD"
        t_hold = stub.mode_times(name, "HOLD")[-1]
        assert _moved_m(stub.track(name), t_hold + 3.0, stub.clock_s(name)) < 1.0  # it holds position
    assert not live.survivors()


def test_bad_missions_exit_2_and_nothing_is_armed(sitl, companion):
    stub = sitl(REFERENCE, speedup=1)
    for path in BAD_MISSIONS:
        run = companion(stub, mission=path, timeout_s=60)
        lines = [line for line in run.stderr.splitlines() if line.strip()]
        assert run.exit_code == 2, (path.name, run.tail)
        assert len(lines) == 1 and lines[0].startswith(str(path)) and "Traceback" not in run.stderr, lines
    for name in ("a", "b"):
        log = stub.vehicle(name)
        assert log.heartbeats > 0 and not any(log.armed_history), (name, log.armed_history)
        assert len(stub.modes(name)) == 1, stub.modes(name)  # no mode was ever commanded
