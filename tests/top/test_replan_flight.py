"""The live pilot re-plans like the headless runner: a vehicle that stops making progress gets a
new A* route from where it is, both free-running in process (the detour is planned inline) and
paced (planned in a worker thread while the vehicle flies its last setpoint).

The scenario is index 0 of the tuning seed 7, where a moving obstacle holds UAV a up long enough
for one detour (never a reporting seed: see docs/results.md).
"""

from __future__ import annotations

import json

import pytest

from companion.cli import main
from uav_model.mission import load_mission
from companion.planning.runner import simulate
from companion.scenarios import generate_scenario, with_variant, write_mission_yaml


@pytest.fixture(scope="module")
def stalling_mission(tmp_path_factory):
    doc = with_variant(generate_scenario(7, 0).doc, "astar-bdwa")
    path = write_mission_yaml(doc, tmp_path_factory.mktemp("replan") / "seed7_i0.yaml")
    headless = simulate(load_mission(path))
    assert headless.success and headless.summary.extra["planner_replans"]["a"] >= 1, \
        "the fixture needs a scenario the headless runner re-plans in"
    return path, headless


@pytest.mark.parametrize("pacing", [[], ["--speedup", "80"]], ids=["free-running-inline", "paced-worker-thread"])
def test_the_companion_replans_a_stalled_vehicle_and_arrives(stalling_mission, pacing, tmp_path, capsys,
                                                             companion_logger):
    path, headless = stalling_mission
    out = tmp_path / "run"
    assert main(["run", str(path), "--in-process", *pacing, "--out", str(out)]) == 0
    assert "no progress for 60 s: new route from" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"]
    a = summary["live"]["vehicles"]["a"]
    assert a["interventions"].get("planner: re-planned", 0) >= 1, a["interventions"]
    assert summary["vehicles"]["a"]["min_obstacle_clearance_m"] > 0.0
    if not pacing:  # the sim waits for the companion: the same flight as the headless runner
        assert summary["vehicles"]["a"]["flight_time_s"] == pytest.approx(
            headless.summary.vehicles["a"].flight_time_s, rel=0.03)
