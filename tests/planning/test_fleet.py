"""N vehicles (issue 15): whom each planner reacts to, and a fleet that keeps every separation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from companion.planning.dwa import NO_OBSTACLES, Command, DwaConfig, OtherUav, Pose, plan_step
from companion.planning.fleet import FleetView, Neighbour, Reaction, react_to, sightline_partner
from companion.planning.metrics import pair_name
from companion.planning.flight.headless import simulate
from companion.scenarios import ScenarioConfig, fleet_layout, generate_scenario
from uav_model.mission import MissionError, mission_from_data

SMALL_FLEET = {"side_m": 1000.0, "static_count": 2, "static_circumradius_m": [40.0, 90.0],
               "moving_count": 1, "moving_radius_m": [20.0, 30.0], "moving_path_m": [150.0, 300.0],
               "moving_speed_m_s": [2.0, 4.0], "station_clearance_m": 100.0, "vehicles": 4}


def _n(name: str, rank: int, x: float, y: float, arrived: bool = False) -> Neighbour:
    return Neighbour(name, rank, OtherUav(x, y, 0.0, 0.0, arrived=arrived))


def test_one_other_vehicle_is_always_the_partner_and_the_whole_separation_set():
    only = _n("a", 0, 3000.0, 0.0)
    reaction = react_to(0.0, 0.0, 1, [only])
    assert reaction.partner is only
    assert reaction.separate_from == (only.uav,)  # not marked as having right of way: pairs unchanged
    assert react_to(0.0, 0.0, 1, []) == Reaction(None, ())


def test_the_nearest_higher_priority_flying_vehicle_is_hidden_from():
    lower = _n("d", 3, 100.0, 0.0)
    boss_parked = _n("a", 0, 150.0, 0.0, arrived=True)
    boss = _n("b", 1, 300.0, 0.0)
    assert sightline_partner(0.0, 0.0, 2, [lower, boss_parked, boss]) is boss
    # the first in priority has nobody to hide from: the nearest
    assert sightline_partner(0.0, 0.0, 0, [lower, boss]) is lower


def test_every_vehicle_is_kept_separated_from_and_the_higher_priority_ones_have_right_of_way():
    lower = _n("d", 3, 100.0, 0.0)
    boss_parked = _n("a", 0, 150.0, 0.0, arrived=True)
    boss = _n("b", 1, 300.0, 0.0)
    reaction = react_to(0.0, 0.0, 2, [lower, boss_parked, boss])
    assert [(u.x_m, u.right_of_way) for u in reaction.separate_from] == [(100.0, False), (150.0, False), (300.0, True)]


@pytest.fixture(scope="module")
def config() -> DwaConfig:
    mission = generate_scenario(11, 0, ScenarioConfig.from_mapping(SMALL_FLEET)).mission
    return DwaConfig.from_settings(mission.planner, mission.vehicles[2], mission.safety)


def test_the_separation_rule_keeps_clear_of_every_vehicle_in_reach_not_only_the_partner(config):
    """Two vehicles ahead, left and right of the straight rollout: a rollout may come near
    neither, though the sightline partner is a third one far away."""
    pose = Pose(0.0, 0.0, 0.0)
    side = config.min_separation_m + 10.0
    left = OtherUav(0.7 * config.reach_m, side, 0.0, 0.0)
    right = OtherUav(0.7 * config.reach_m, -side, 0.0, 0.0)
    far = OtherUav(-5000.0, 0.0, 0.0, 0.0)
    goal = (2.0 * config.reach_m, 0.0)
    both = plan_step(pose, goal, far, NO_OBSTACLES, config, separate_from=(left, right, far))
    one = plan_step(pose, goal, far, NO_OBSTACLES, config, separate_from=(left,))
    assert isinstance(both, Command) and isinstance(one, Command)
    assert 0 < both.legal_count < one.legal_count < config.count
    i = int(np.flatnonzero(config.yaw_rates_rad_s == both.yaw_rate_rad_s)[0])
    px, py = config.body_xy_m[i, :, 0], config.body_xy_m[i, :, 1]
    for u in (left, right):
        assert np.hypot(px - u.x_m, py - u.y_m).min() >= config.min_separation_m - 1e-6
    # the partner alone is out of reach: every rollout is legal
    assert plan_step(pose, goal, far, NO_OBSTACLES, config).legal_count == config.count


def test_a_vehicle_with_right_of_way_is_kept_clear_of_by_the_yield_margin_more(config):
    pose = Pose(0.0, 0.0, 0.0)
    gap = config.min_separation_m + config.yield_margin_m / 2  # off the straight rollout's end
    uav = OtherUav(config.reach_m, gap, 0.0, 0.0)
    straight = config.count // 2
    equal = plan_step(pose, (config.reach_m, 0.0), None, NO_OBSTACLES, config, separate_from=(uav,))
    boss = plan_step(pose, (config.reach_m, 0.0), None, NO_OBSTACLES, config,
                     separate_from=(replace(uav, right_of_way=True),))
    assert config.yield_margin_m > 0 and isinstance(equal, Command) and isinstance(boss, Command)
    assert equal.yaw_rate_rad_s == config.yaw_rates_rad_s[straight]  # far enough: straight on
    assert boss.yaw_rate_rad_s < 0.0  # not far enough from one with right of way: gives way to the right


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


def test_eight_vehicles_meeting_at_the_centre_keep_every_separation():
    """The perimeter layout's eight vehicles, all through the centre at once (no obstacles, a
    1 km square to keep it short): reacting to one vehicle at a time, the planners lost the
    separation there (48.6 m); keeping clear of all of them, and lower priority giving way,
    every one of the 28 pairs keeps it and every vehicle arrives."""
    side = 1000.0
    fleet = fleet_layout(side, 8)
    doc = {"name": "eight_converging_small", "plant": "multicopter",
           "area": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": side, "y_max_m": side, "geofence_margin_m": 200.0},
           "stations": fleet["stations"], "obstacles": [], "vehicles": fleet["vehicles"]}
    mission = mission_from_data(doc, "eight_converging_small")
    summary = simulate(mission).summary
    assert summary.success, summary.reason
    assert len(summary.pairs) == 28
    assert min(p.min_separation_m for p in summary.pairs.values()) >= mission.safety.min_separation_m


@pytest.mark.parametrize("seed", range(6))
def test_the_fleet_view_answers_as_react_to_leaving_out_only_the_uavs_out_of_reach(seed):
    """The tick loop's one-matrix view (FleetView) against react_to per vehicle, on random fleets
    with some vehicles parked and some assigned partners."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(3, 12))
    names = [f"v{i}" for i in range(count)]
    xy = rng.uniform(0.0, 1500.0, (count, 2))
    uavs = [OtherUav(x, y, 0.0, 0.0, arrived=True) if rng.random() < 0.2 else OtherUav(x, y, *rng.uniform(-10, 10, 2))
            for x, y in xy]
    partners = [None if rng.random() < 0.6 else set(rng.choice(names, 2)) for _ in names]
    reach = (400.0, 20.0)
    view = FleetView(xy, uavs, names, partners, [reach] * count)
    for i in range(count):
        neighbours = [Neighbour(names[j], j, uavs[j]) for j in range(count) if j != i]
        expected = react_to(*xy[i], i, neighbours, partners[i])
        got = view.reaction(i)
        assert got.partner == expected.partner
        kept = [u for u in expected.separate_from
                if np.hypot(u.x_m - xy[i][0], u.y_m - xy[i][1]) <= reach[0] + np.hypot(u.vx_m_s, u.vy_m_s) * reach[1]]
        assert list(got.separate_from) == kept
