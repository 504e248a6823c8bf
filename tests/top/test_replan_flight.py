"""The live pilot re-plans like the headless runner: a vehicle that stops making progress gets a
new A* route from where it is, both free-running in process (the detour is planned inline) and
paced (planned in a worker thread while the vehicle flies its last setpoint).

The scenario is index 0 of the tuning seed 7, where a moving obstacle holds UAV a up long enough
for one detour (never a reporting seed: see docs/results.md).
"""

from __future__ import annotations

import pytest

from uav_model.mission import load_mission
from companion.planning.flight.headless import simulate
from companion.scenarios import generate_scenario, with_variant, write_mission_yaml


@pytest.fixture(scope="module")
def stalling_mission(tmp_path_factory):
    doc = with_variant(generate_scenario(7, 0).doc, "astar-bdwa")
    path = write_mission_yaml(doc, tmp_path_factory.mktemp("replan") / "seed7_i0.yaml")
    headless = simulate(load_mission(path))
    assert headless.success and headless.summary.planner["a"].stall_detours >= 1, \
        "the fixture needs a scenario the headless runner detours in"
    return path, headless


@pytest.mark.parametrize("pacing", [[], ["--speedup", "80"]], ids=["free-running-inline", "paced-worker-thread"])
def test_the_companion_replans_a_stalled_vehicle_and_arrives(stalling_mission, pacing, run_in_process):
    path, headless = stalling_mission
    run = run_in_process(path, *pacing)
    assert "no progress for 60 s: new route from" in run.stdout
    summary = run.summary
    assert summary["success"]
    a = summary["live"]["vehicles"]["a"]
    assert a["interventions"].get("planner: re-planned", 0) >= 1, a["interventions"]
    assert summary["vehicles"]["a"]["min_obstacle_clearance_m"] > 0.0
    if not pacing:  # the sim waits for the companion: the same flight as the headless runner
        assert summary["vehicles"]["a"]["flight_time_s"] == pytest.approx(
            headless.summary.vehicles["a"].flight_time_s, rel=0.03)
