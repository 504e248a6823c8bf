"""``companion run --in-process``: the whole companion (pilots, monitors, flight log, scoring) flies
the reference mission against the stub's vehicles in this process, with no stub process and no
sockets. Not marked slow: the ~480 s mission takes a few seconds of wall time.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from companion.cli import main
from uav_model.mission import load_mission
from companion.planning.runner import simulate

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"


def test_reference_mission_in_process_matches_the_headless_runner(tmp_path, capsys, companion_logger):
    out = tmp_path / "run"
    assert main(["run", str(REFERENCE), "--in-process", "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "SUCCESS" in stdout and "no .tlog (in process" in stdout

    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"] and summary["live"]["connections"] == "in-process"
    assert summary["occlusion_certificate"]["verdict"] == "needs-hold"  # a would have to hold (docs/design.md)
    headless = simulate(load_mission(REFERENCE)).summary
    for name in ("a", "b"):
        flown = summary["vehicles"][name]
        live = summary["live"]["vehicles"][name]
        assert flown["arrived"] and live["landed"] and live["phase"] == "landed", (name, live)
        # Same planner, same plant, same scoring as `companion simulate`, through the MAVLink state machine.
        assert flown["flight_time_s"] == pytest.approx(headless.vehicles[name].flight_time_s, rel=0.03), name
        assert live["offboard_reentries"] == 0, live  # setpoints never lapsed: the sim waits for the companion

    rows = list(csv.DictReader((out / "flight.csv").read_text().splitlines()))
    ticks = [r for r in rows if r["vehicle"] == "a" and r["action"] == "fly"]
    assert len(ticks) > 800  # one tick per 0.5 s of sim time over ~480 s
    assert max(abs(float(r["cmd_yaw_rate_deg_s"])) for r in ticks) <= math.degrees(10.0 / 30.0) + 1e-6
    assert (out / "trajectory.png").stat().st_size > 10_000
