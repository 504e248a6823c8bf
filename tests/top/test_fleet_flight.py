"""``companion run`` with eight vehicles (issue 15), in process: the whole companion (a pilot per
vehicle, monitors, scoring) against the stub's eight vehicles on one sim clock. Over UDP at 20x
the same mission takes ~95 s wall on the shared machine, so it is measured by
``benchmarks/bench_fleet.py`` instead of a test. Marked slow all the same: in process it costs
~40 s of CPU (eight pilots over ~380 s of sim time)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.cli import main
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
EIGHT = ROOT / "missions" / "eight_vehicles.yaml"


@pytest.mark.slow
@pytest.mark.timeout(600)  # ~40 s of CPU; in process the sim waits for it, so only wall time grows under load
def test_eight_vehicles_fly_in_process_and_keep_every_separation(tmp_path, capsys, companion_logger):
    mission = load_mission(EIGHT)
    assert len(mission.vehicles) == 8 and len({v.goal for v in mission.vehicles}) == 8
    out = tmp_path / "run"
    assert main(["run", str(EIGHT), "--in-process", "--out", str(out), "--progress-every", "1000"]) == 0
    assert "SUCCESS" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"]
    for name, live in summary["live"]["vehicles"].items():
        assert summary["vehicles"][name]["arrived"] and live["landed"], (name, live)
    assert len(summary["pairs"]) == 28
    for pair, metrics in summary["pairs"].items():
        assert metrics["min_separation_m"] >= mission.safety.min_separation_m, pair
