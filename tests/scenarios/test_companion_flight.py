"""``companion run`` end to end over real UDP: MAVSDK links, the stub's PX4-like vehicles, and the
vehicles' own telemetry as the judge.

Each test uses free UDP ports, so the file runs in parallel under xdist. Expectations come from the
mission file, from ``companion simulate`` on the same mission, or from a GCS-side recorder on the
stub, never from the companion's opinion of itself alone.
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.mission import load_mission
from companion.planning.runner import simulate
from companion.testing.plugin import free_udp_port, free_udp_port_block

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
MOVING = ROOT / "missions" / "moving_obstacles.yaml"
BAD_MISSIONS = sorted((ROOT / "tests" / "data" / "bad_missions").glob("*.yaml"))

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _kill_group(proc: subprocess.Popen, sig: int = signal.SIGKILL) -> None:
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass


def _companion(*args: str) -> list[str]:
    return [sys.executable, "-m", "companion.cli", *args]


def _run(args: list[str], timeout_s: float = 180.0) -> subprocess.CompletedProcess:
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        out, err = proc.communicate()
        raise AssertionError(f"companion did not finish in {timeout_s:g} s\n{out[-3000:]}\n{err[-3000:]}") from None
    finally:
        _kill_group(proc)  # nothing of the group may outlive the test
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


def _embedded_run(mission: Path, out: Path, *extra: str) -> tuple[subprocess.CompletedProcess, int]:
    base = free_udp_port_block(2)
    result = _run(_companion("run", str(mission), "--speedup", "20", "--out", str(out), "--port-base", str(base),
                             "--gcs-port", str(free_udp_port()), *extra))
    return result, base


def _processes_with(*needles: bytes) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if all(n in cmdline for n in needles):
            found.append(int(entry.name))
    return found


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.read_text().splitlines()))


def test_reference_mission_flies_end_to_end_like_simulate(tmp_path):
    result, base = _embedded_run(REFERENCE, tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["success"] and summary["reason"] is None
    assert all(v["arrived"] for v in summary["vehicles"].values())
    assert summary["min_separation_m"] >= 50.0
    assert all(v["min_obstacle_clearance_m"] > 0.0 for v in summary["vehicles"].values())

    # Same planner, same plant, same scoring: flight times within 3 % of the headless runner's.
    headless = simulate(load_mission(REFERENCE)).summary
    for name, v in summary["vehicles"].items():
        expected = headless.vehicles[name].flight_time_s
        assert v["flight_time_s"] == pytest.approx(expected, rel=0.03), (name, v["flight_time_s"], expected)
    assert summary["live"]["vehicles"]["a"]["landed"] and summary["live"]["vehicles"]["b"]["landed"]

    rows = _rows(tmp_path / "flight.csv")
    assert {r["vehicle"] for r in rows} == {"a", "b"}
    ticks = [r for r in rows if r["vehicle"] == "a" and r["action"] == "fly"]
    assert len(ticks) > 800  # one tick per 0.5 s of sim time over ~480 s
    assert max(abs(float(r["cmd_yaw_rate_deg_s"])) for r in ticks) <= math.degrees(10.0 / 30.0) + 1e-6
    assert (tmp_path / "trajectory.png").stat().st_size > 10_000
    tlogs = list(tmp_path.glob("*.tlog"))
    assert tlogs and tlogs[0].stat().st_size > 10_000
    assert "SUCCESS" in result.stdout and "a: arrived" in result.stdout
    assert not _processes_with(b"stub_child", str(base).encode()), "the embedded stub outlived the companion"


def test_moving_obstacles_reach_the_companion_over_mavlink(tmp_path):
    mission = load_mission(MOVING)
    result, _ = _embedded_run(MOVING, tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert json.loads((tmp_path / "summary.json").read_text())["success"]

    # traffic.csv is what the companion decoded from ADSB_VEHICLE (lat/lon, course, speed): it must
    # match the mission's motion model at the vehicle clock the report came in with.
    rows = _rows(tmp_path / "traffic.csv")
    moving = {o.id: o for o in mission.world.moving_obstacles}
    assert {r["callsign"] for r in rows} == set(moving)
    assert {r["via"] for r in rows} == {"a", "b"}
    errors, vel_errors = [], []
    for r in rows:
        o = moving[r["callsign"]]
        t = float(r["t_sim_s"])
        x, y = o.center_at(t)
        errors.append(math.hypot(float(r["x_m"]) - x, float(r["y_m"]) - y))
        v_now, v_before = np.array(o.motion.velocity_at(t)), np.array(o.motion.velocity_at(t - 0.5))
        if np.allclose(v_now, v_before, atol=0.05):  # skip the instants a shuttle turns round
            vel_errors.append(float(np.hypot(*(np.array([float(r["vx_m_s"]), float(r["vy_m_s"])]) - v_now))))
    assert len(rows) > 200
    # A report is stamped with the receiving vehicle's latest clock: at most one stream period
    # (0.2 s sim at 20x) after it was sent, i.e. about a metre at these speeds.
    assert np.median(errors) < 1.5 and max(errors) < 5.0, (np.median(errors), max(errors))
    assert max(vel_errors) < 0.05


def test_reference_mission_survives_loss_and_latency(tmp_path):
    result, _ = _embedded_run(REFERENCE, tmp_path, "--loss", "0.05", "--latency-ms", "100", "--seed", "7")
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["success"], summary["reason"]
    assert summary["live"]["loss"] == 0.05 and summary["live"]["latency_ms"] == 100.0


def test_a_telemetry_blackout_makes_the_vehicles_hover_then_resume(tmp_path):
    # 3 s (sim) of silence on both API links, mid-flight: no position, no setpoint gets through.
    result, _ = _embedded_run(REFERENCE, tmp_path, "--blackout", "150:3")
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["success"]
    rows = _rows(tmp_path / "flight.csv")
    for name in ("a", "b"):
        assert summary["live"]["vehicles"][name]["interventions"].get("stale", 0) >= 1
        stale = [r for r in rows if r["vehicle"] == name and r["note"].startswith("stale")]
        assert stale and all(r["action"] == "hover" for r in stale)
        # Logged at the last clock heard, i.e. just before the silence began.
        assert 149.0 < float(stale[0]["t_sim_s"]) <= 150.0
        flown = [float(r["t_sim_s"]) for r in rows if r["vehicle"] == name and r["action"] == "fly"]
        assert not any(150.0 < t < 153.0 for t in flown)  # nothing planned on data from the silence
        assert max(flown) > 400.0  # and the flight went on


def _start_companion(sitl, out: Path) -> subprocess.Popen:
    return subprocess.Popen(_companion("run", str(sitl.mission_path), *sitl.connect_args(), "--out", str(out)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_both_departed(sitl, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    for name in ("a", "b"):
        try:
            sitl.wait_for_mode(name, "OFFBOARD", timeout_s=timeout_s)
        except TimeoutError:
            _kill_group(proc)
            out, err = proc.communicate()
            raise AssertionError(f"{name} never reached OFFBOARD\n{out[-2000:]}\n{err[-2000:]}") from None
    t0 = sitl.vehicle("a").t_s[-1]
    sitl.telemetry.wait_until(lambda r: sitl.vehicle("a").t_s[-1] > t0 + 20.0, timeout_s=30.0,
                              what="20 s of offboard flight")


def test_killed_companion_leaves_both_vehicles_holding(sitl, tmp_path):
    stub = sitl(REFERENCE, speedup=20)
    proc = _start_companion(stub, tmp_path)
    try:
        _wait_both_departed(stub, proc)
        _kill_group(proc)  # SIGKILL: no cleanup at all, as in a crash
        proc.communicate(timeout=10)
        for name in ("a", "b"):
            # The autopilot's own failsafe: setpoints stop, HOLD after COM_OF_LOSS_T (1 s sim).
            stub.wait_for_mode(name, "HOLD", timeout_s=10.0)
        time.sleep(0.5)
        for name in ("a", "b"):
            modes = stub.modes(name)
            assert modes[-1] == "HOLD" and "OFFBOARD" in modes, modes
            assert stub.vehicle(name).armed
            assert any("Offboard" in text for text in stub.vehicle(name).statustext)
    finally:
        _kill_group(proc)


def test_sigterm_stops_offboard_holds_and_reports(sitl, tmp_path):
    stub = sitl(REFERENCE, speedup=20)
    proc = _start_companion(stub, tmp_path)
    try:
        _wait_both_departed(stub, proc)
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        _kill_group(proc)
    assert proc.returncode == 1, out[-2000:] + err[-2000:]
    for name in ("a", "b"):
        assert stub.modes(name)[-1] == "HOLD"
        # The companion asked for it (offboard stop), not the offboard-loss failsafe.
        assert not any("Offboard control lost" in text for text in stub.vehicle(name).statustext)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["reason"] == "interrupted" and not summary["success"]
    assert "holding position" in out and "FAILED (interrupted)" in out
    flight = _rows(tmp_path / "flight.csv")
    assert len([r for r in flight if r["action"] == "fly"]) > 50


def test_bad_missions_are_refused_before_anything_is_armed(sitl):
    stub = sitl(REFERENCE, speedup=20)
    for path in BAD_MISSIONS:
        result = _run(_companion("run", str(path), *stub.connect_args()), timeout_s=60.0)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert result.returncode == 2, (path.name, result.stdout, result.stderr)
        assert len(lines) == 1 and lines[0].startswith(str(path)) and "Traceback" not in result.stderr, lines
    for name in ("a", "b"):
        log = stub.vehicle(name)
        assert log.heartbeats > 0 and not any(log.armed_history), (name, log.armed_history)
        assert stub.modes(name) == [stub.modes(name)[0]]  # no mode was ever commanded


def test_upload_stores_the_planned_route_on_each_vehicle(sitl):
    from companion.app.flight_plan import prepare

    stub = sitl(REFERENCE, speedup=20)
    result = _run(_companion("upload", str(REFERENCE), *stub.connect_args()), timeout_s=60.0)
    assert result.returncode == 0, result.stdout + result.stderr
    plan = prepare(load_mission(REFERENCE))
    for v in plan.mission.vehicles:
        # Downloaded by a GCS, independently of MAVSDK: the sparse A* nodes, in order.
        stored = stub.mission_on_vehicle(v.name)
        expected = stub.plan_as_geodetic(plan.routes[v.name].sparse_enu_m)
        assert len(stored) == len(expected) == plan.routes[v.name].nodes_sparse
        for (lat, lon), (elat, elon) in zip(stored, expected):
            assert abs(lat - elat) < 2e-7 and abs(lon - elon) < 2e-7
        assert not any(stub.vehicle(v.name).armed_history)


def test_a_refused_arm_aborts_cleanly_and_nobody_takes_off(sitl, tmp_path):
    # The stub refuses to arm below BAT_CRIT_THR (7 %), as PX4 does: vehicle b is nearly empty.
    text = REFERENCE.read_text().replace("battery_pct: 35.0", "battery_pct: 5.0")
    assert "battery_pct: 5.0" in text
    mission_path = tmp_path / "weak_battery.yaml"
    mission_path.write_text(text)
    stub = sitl(mission_path, speedup=20)
    result = _run(_companion("run", str(mission_path), *stub.connect_args(), "--out", str(tmp_path / "out")),
                  timeout_s=90.0)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "vehicle 'b': arm refused" in result.stdout
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["reason"] == "command_refused"
    time.sleep(0.5)
    for name in ("a", "b"):
        log = stub.vehicle(name)
        assert not log.armed, name  # a armed, then was disarmed again; b never armed
        assert max(log.z_m, default=0.0) < 1.0  # nobody left the ground
    assert not any(stub.vehicle("b").armed_history)
