"""N vehicles (issue 15): whom each planner reacts to, and a fleet that keeps every separation."""

from __future__ import annotations

import pytest

from companion.planning.dwa import DwaConfig, OtherUav
from companion.planning.fleet import Neighbour, choose_other
from companion.planning.metrics import pair_name
from companion.planning.runner import simulate
from companion.scenarios import ScenarioConfig, generate_scenario
from uav_model.mission import MissionError, mission_from_data

SMALL_FLEET = {"side_m": 1000.0, "static_count": 2, "static_circumradius_m": [40.0, 90.0],
               "moving_count": 1, "moving_radius_m": [20.0, 30.0], "moving_path_m": [150.0, 300.0],
               "moving_speed_m_s": [2.0, 4.0], "station_clearance_m": 100.0, "vehicles": 4}


@pytest.fixture(scope="module")
def config() -> DwaConfig:
    mission = generate_scenario(11, 0, ScenarioConfig.from_mapping(SMALL_FLEET)).mission
    return DwaConfig.from_settings(mission.planner, mission.vehicles[2], mission.safety)


def _n(name: str, rank: int, x: float, y: float, arrived: bool = False) -> Neighbour:
    return Neighbour(name, rank, OtherUav(x, y, 0.0, 0.0, arrived=arrived))


def test_one_other_vehicle_is_always_the_one(config):
    only = _n("a", 0, 3000.0, 0.0)
    assert choose_other(0.0, 0.0, 1, [only], config) is only
    assert choose_other(0.0, 0.0, 1, [], config) is None


def test_a_vehicle_within_separation_reach_comes_first_whatever_its_priority(config):
    close = _n("d", 3, config.reach_m, 0.0)
    boss = _n("a", 0, 2000.0, 0.0)
    assert choose_other(0.0, 0.0, 2, [boss, close], config) is close


def test_otherwise_the_nearest_higher_priority_flying_vehicle_is_hidden_from(config):
    far = 10 * (config.reach_m + config.min_separation_m)
    lower = _n("d", 3, far, 0.0)
    boss_parked = _n("a", 0, 1.5 * far, 0.0, arrived=True)
    boss = _n("b", 1, 3 * far, 0.0)
    assert choose_other(0.0, 0.0, 2, [lower, boss_parked, boss], config) is boss
    # the first in priority has nobody to hide from: the nearest
    assert choose_other(0.0, 0.0, 0, [lower, boss], config) is lower


def test_a_generated_four_vehicle_scenario_keeps_every_pair_separated():
    """Issue 10's acceptance: every pair of a generated 4-vehicle scenario keeps its separation."""
    scenario = generate_scenario(11, 0, ScenarioConfig.from_mapping(SMALL_FLEET))
    mission = scenario.mission
    assert len(mission.vehicles) == 4
    summary = simulate(mission, routes=scenario.routes).summary
    assert summary.success, summary.reason
    names = [v.name for v in mission.by_priority]
    assert list(summary.pairs) == [pair_name(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    for pair in summary.pairs.values():
        assert pair.min_separation_m >= mission.safety.min_separation_m
    assert summary.min_separation_m == min(p.min_separation_m for p in summary.pairs.values())
    headline = summary.pairs[pair_name(names[0], names[1])]
    assert summary.los_blocked_fraction == headline.los_blocked_fraction
    assert summary.summary_dict()["pairs"].keys() == summary.pairs.keys()


def test_routes_of_more_than_two_vehicles_are_not_constrained_by_each_other():
    scenario = generate_scenario(11, 0, ScenarioConfig.from_mapping(SMALL_FLEET))
    assert {r.constraint for r in scenario.routes.values()} == {"none"}
    pair = generate_scenario(11, 0, ScenarioConfig.from_mapping({**SMALL_FLEET, "vehicles": 2}))
    assert len(pair.routes) == 2


def test_a_shared_goal_is_still_refused_with_many_vehicles():
    doc = generate_scenario(11, 0, ScenarioConfig.from_mapping(SMALL_FLEET)).doc
    doc["vehicles"][3]["goal"] = doc["vehicles"][2]["goal"]
    with pytest.raises(MissionError, match="already the goal"):
        mission_from_data(doc, "fleet")
