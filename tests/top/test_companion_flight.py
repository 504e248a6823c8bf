"""``companion run`` / ``upload`` behaviour of its own, over real UDP with the harness's stub:
an operator's SIGTERM, a weak battery refused before arming, an upload without a flight.

The scenario flights (reference, moving obstacles, random scenarios) and the link faults are in
test_harness_scenarios.py and test_harness_faults.py; they also check the companion's outputs
(flight.csv, traffic.csv, summary.json, the embedded stub) on the flights they make anyway.
"""

from __future__ import annotations

import csv
import io
import signal
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _fly_rows_written(path: Path, at_least: int, timeout_s: float) -> int:
    """How many planner ticks ("fly" rows) the companion has flushed to ``path``, polled until
    there are ``at_least`` or ``timeout_s`` of wall time passed (a half-written last line is not counted)."""
    deadline = time.monotonic() + timeout_s
    while True:
        text = path.read_text() if path.exists() else ""
        complete = text[:text.rfind("\n") + 1]
        n = sum(1 for r in csv.DictReader(io.StringIO(complete)) if r.get("action") == "fly")
        if n >= at_least or time.monotonic() > deadline:
            return n
        time.sleep(0.1)


def test_sigterm_stops_offboard_holds_and_reports(sitl, companion):
    stub = sitl(REFERENCE, speedup=20)
    live = companion.start(stub)
    for name in ("a", "b"):
        stub.wait_for_mode(name, "OFFBOARD", timeout_s=60)
    stub.wait_for_clock(stub.mode_times("a", "OFFBOARD")[0] + 20.0)
    # Under load the companion ticks behind the stub's clock: wait for its own log to show it flying.
    flown = _fly_rows_written(live.out_dir / "flight.csv", at_least=40, timeout_s=15.0)
    assert flown >= 40, f"only {flown} planner ticks logged 20 s of sim into the flight"
    sent_wall_s = time.monotonic()
    live.signal(signal.SIGTERM)
    run = live.wait(30)
    assert run.exit_code == 1, run.tail
    for name in ("a", "b"):
        assert stub.modes(name)[-1] == "HOLD"
        assert stub.vehicle(name).armed  # still airborne, holding: the operator decides what next
        # The companion asked for it (offboard stop), not the offboard-loss failsafe.
        failsafes = [text for wall, _, text in stub.vehicle(name).statustexts
                     if wall > sent_wall_s and "Offboard control lost" in text]
        assert not failsafes, (name, failsafes)
    assert run.summary["reason"] == "interrupted" and not run.summary["success"]
    assert "holding position" in run.stdout and "FAILED (interrupted)" in run.stdout
    assert len([r for r in run.flight_log() if r["action"] == "fly"]) >= flown  # no logged tick lost
    assert not live.survivors()


def test_a_weak_battery_is_refused_before_anything_arms(sitl, companion, tmp_path):
    # Vehicle b is nearly empty (the stub would refuse to arm it below BAT_CRIT_THR, 7 %, as PX4
    # does): the pre-flight battery check refuses the flight first, with the numbers, exit 2.
    text = REFERENCE.read_text().replace("battery_pct: 35.0", "battery_pct: 5.0")
    assert "battery_pct: 5.0" in text
    mission_path = tmp_path / "weak_battery.yaml"
    mission_path.write_text(text)
    stub = sitl(mission_path, speedup=20)
    run = companion(stub, timeout_s=90)
    assert run.exit_code == 2, run.tail
    assert "vehicle 'b': pre-flight: 5 %, the mission needs ~" in run.stderr and "nothing was armed" in run.stderr
    time.sleep(0.5)  # a stray arm would show on the GCS link by now
    for name in ("a", "b"):
        assert not any(stub.vehicle(name).armed_history), name
        assert max(p[3] for p in stub.vehicle(name).positions) < 1.0  # nobody left the ground


def test_upload_stores_the_planned_route_on_each_vehicle(sitl, companion):
    stub = sitl(REFERENCE, speedup=20)
    result = companion.cli("upload", REFERENCE, *stub.connect_args(), timeout_s=60)
    assert result.returncode == 0, result.stdout + result.stderr
    stub.assert_mission_matches_plan()  # downloaded by the GCS, independently of MAVSDK
    for name in ("a", "b"):
        assert not any(stub.vehicle(name).armed_history)
