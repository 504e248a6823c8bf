"""The ORCA baseline (issue 15): an extra bench variant that leaves the other variants' rows alone."""

from __future__ import annotations

import importlib.util

import pytest

from companion.bench.execute import run_bench
from companion.bench.orca import ORCA, simulate_orca
from companion.scenarios import ScenarioConfig, generate_scenario

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pyrvo") is None,
                                reason="needs the orca extra: pip install -e '.[orca]'")

SMALL = {"side_m": 1000.0, "static_count": 2, "static_circumradius_m": [40.0, 90.0],
         "moving_count": 1, "moving_radius_m": [20.0, 30.0], "moving_path_m": [150.0, 300.0],
         "moving_speed_m_s": [2.0, 4.0], "station_clearance_m": 100.0}


def _timeless(rows):
    return [{k: v for k, v in r.items() if k not in ("wall_s", "planner_ms_per_tick")} for r in rows]


def test_orca_rows_sit_beside_the_variants_without_changing_them():
    cfg = ScenarioConfig.from_mapping(SMALL)
    alone = run_bench(7, 2, ["astar-bdwa"], workers=1, config=cfg, progress=None)
    both = run_bench(7, 2, ["astar-bdwa", ORCA], workers=1, config=cfg, progress=None)
    assert _timeless([r for r in both if r["variant"] == "astar-bdwa"]) == _timeless(alone)
    orca = [r for r in both if r["variant"] == ORCA]
    assert len(orca) == 2 and all(r["reason"] != "error" for r in orca), orca
    assert all(r["min_separation_m"] is not None and r["a_flight_time_s"] > 0 for r in orca)


def test_orca_flies_a_four_vehicle_fleet_through_the_same_scoring():
    scenario = generate_scenario(11, 0, ScenarioConfig.from_mapping({**SMALL, "vehicles": 4}))
    result = simulate_orca(scenario.mission, routes=scenario.routes)
    summary = result.summary
    assert result.variant == ORCA and len(summary.pairs) == 6
    assert summary.success, summary.reason  # every vehicle arrived, no collision, no separation loss
    assert summary.min_separation_m >= scenario.mission.safety.min_separation_m
