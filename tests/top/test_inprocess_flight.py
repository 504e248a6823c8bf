"""``companion run --in-process``: the whole companion (pilots, monitors, flight log, scoring) flies
the reference mission against the stub's vehicles in this process, with no stub process and no
sockets. Not marked slow: the ~480 s mission takes a few seconds of wall time.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"


def test_reference_mission_in_process_matches_the_headless_runner(run_in_process, reference_headless):
    run = run_in_process(REFERENCE)
    assert "SUCCESS" in run.stdout and "no .tlog (in process" in run.stdout

    summary, out = run.summary, run.out_dir
    assert summary["success"] and summary["live"]["connections"] == "in-process"
    assert summary["occlusion_certificate"]["verdict"] == "needs-hold"  # a would have to hold (docs/design.md)
    for name in ("a", "b"):
        flown = summary["vehicles"][name]
        live = summary["live"]["vehicles"][name]
        assert flown["arrived"] and live["landed"] and live["phase"] == "landed", (name, live)
        # Same planner, same plant, same scoring as `companion simulate`, through the MAVLink state machine.
        assert flown["flight_time_s"] == pytest.approx(reference_headless.vehicles[name].flight_time_s, rel=0.03), name
        assert live["offboard_reentries"] == 0, live  # setpoints never lapsed: the sim waits for the companion

    rows = list(csv.DictReader((out / "flight.csv").read_text().splitlines()))
    ticks = [r for r in rows if r["vehicle"] == "a" and r["action"] == "fly"]
    assert len(ticks) > 800  # one tick per 0.5 s of sim time over ~480 s
    # flight.csv keeps 3 decimals: a command at the limit (19.0986 deg/s) reads 19.099
    assert max(abs(float(r["cmd_yaw_rate_deg_s"])) for r in ticks) <= math.degrees(10.0 / 30.0) + 5e-4
    assert (out / "trajectory.png").stat().st_size > 10_000
