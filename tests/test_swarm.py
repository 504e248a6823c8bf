"""A swarm's meetings, flown headless with the default variant: every vehicle arrives, none
touches an obstacle, no two come closer than the mission's minimum separation, and each assigned
sight-line pair ends its closest approach with the line blocked.

The missions are :mod:`companion.formations`' small shapes (at most 1.7 km across), so each
flight takes seconds. A failure is a behaviour the planner lacks: it stays here, marked
``xfail(strict=True)`` with what goes wrong, until the planner gets it right.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from companion.formations import corridor, crossing_lanes, ring
from companion.scenarios import ScenarioConfig, generate_scenario
from companion.planning.coordination.plan import plan_coordinated
from companion.planning.coordination.search import Blocking
from companion.planning.flight.forecast import mission_certificate, mission_certificates
from companion.planning.flight.headless import RunResult, flight_inputs, simulate, simulate_certified
from companion.planning.metrics import FailureReason, Track
from companion.testing.assertions import TelemetryAssertions
from uav_model.mission import load_mission, mission_from_data

ROOT = Path(__file__).resolve().parents[1]


class Flown(TelemetryAssertions):
    """The harness's assertions over a headless flight's tracks (no modes: nothing flew over MAVLink)."""

    def __init__(self, run: RunResult) -> None:
        self.mission, self.run = run.mission, run

    def track(self, name: str, since_mode: str | None = None) -> Track:
        return self.run.tracks[name]

    def modes(self, name: str) -> list[str]:
        return []

    def mode_times(self, name: str, mode: str) -> list[float]:
        return []


def fly(doc: dict) -> Flown:
    return Flown(simulate(mission_from_data(doc, doc["name"])))


def assert_safe_arrivals(flown: Flown) -> None:
    flown.assert_success()  # every arrival, clearance, separation (between samples too), geofence
    summary = flown.run.summary
    assert summary.success, (summary.reason, summary.failure_t_s)
    assert summary.min_separation_m >= flown.mission.safety.min_separation_m


def test_a_ring_of_16_converging_on_one_point_all_arrive_with_the_separation_kept():
    flown = fly(ring(16, 400.0))
    assert len(flown.mission.vehicles) == 16
    assert_safe_arrivals(flown)


@pytest.mark.parametrize("gap_m", [120.0, 150.0, 200.0])
def test_four_lanes_crossing_four_all_arrive_with_the_separation_kept(gap_m):
    """At 150 m a vehicle passed one hovering off its lane at 49.9 m: its rollouts kept 55 m, the
    multicopter flew wide of their turn. The separation is kept on the rollouts as flown too."""
    flown = fly(crossing_lanes(4, gap_m))
    assert_safe_arrivals(flown)


@pytest.mark.parametrize("seed, index, vehicles", [(9091, 12, 8), (9091, 0, 16)])
def test_boxed_in_vehicles_escape_without_flying_into_an_obstacle(seed, index, vehicles):
    """Generated scenarios where a vehicle with no legal rollout escaped along turns that only
    grazed a true footprint, and the multicopter, trailing its heading, flew into it: e into a
    moving disc after 24 escape ticks; n into a static triangle after 49."""
    scenario = generate_scenario(seed, index, ScenarioConfig(vehicles=vehicles))
    assert_safe_arrivals(Flown(simulate(scenario.mission, "astar-bdwa", routes=scenario.routes)))


def test_a_vehicle_yawing_in_place_keeps_its_way_round_until_it_faces_the_heading_it_set_out_for():
    """Seed 9293, scenario 14 of 8: e, having given way, ended up 47 m outside the fence, every
    rollout from its heading leading further out. The spin recovery's best heading flipped each
    tick between one 153 deg to its left and one 172 deg to its right (the goal straight behind
    it): e yawed one tick left, one tick right, for 2,000 s, until the time limit."""
    scenario = generate_scenario(9293, 14, ScenarioConfig(vehicles=8))
    flown = Flown(simulate(scenario.mission, "astar-bdwa", routes=scenario.routes))
    assert_safe_arrivals(flown)
    kept = [t for t in flown.run.ticks["e"] if t.recovery_reason and "kept turning" in t.recovery_reason]
    assert kept  # the overruled picks, which turned it back the other way


@pytest.mark.parametrize("seed, index, vehicles", [(9192, 3, 16), (9192, 6, 16), (9192, 8, 16)])
def test_the_first_240_s_of_a_crowded_meeting_touch_nothing_and_keep_the_separation(seed, index, vehicles):
    """Generated scenarios of 16 where, by 200 s, a vehicle boxed in by the others and an obstacle
    escaped into the obstacle, or one stopped short of another without room to stop:
    - 3: l, kept 70 m from a vehicle with right of way, escaped for 19 s along a static square,
      each tick deeper into its margin, until it touched it;
    - 6: p, likewise squeezed between two vehicles with right of way, into a moving disc;
    - 8: b, with right of way, turned past o hovering along arcs that kept 55-56 m from it (the
      multicopter flying them keeps 45-50 m), found no legal rollout and, braking, came within
      49.2 m of it.
    The escape may use the right of way's margin before an obstacle's inflation, the separation
    is kept on the rollouts as flown, and a hover is judged on the braking segment of the
    vehicle's own velocity. Flown to 240 s (the meetings are over, the arrivals are not)."""
    scenario = generate_scenario(seed, index, ScenarioConfig(vehicles=vehicles))
    mission = scenario.mission
    mission = dataclasses.replace(mission, safety=dataclasses.replace(mission.safety, time_limit_s=240.0))
    summary = simulate(mission, "astar-bdwa", routes=scenario.routes).summary
    assert summary.reason is FailureReason.TIMEOUT and summary.failure_t_s == 240.0, summary.reason
    assert summary.min_separation_m >= mission.safety.min_separation_m


def test_a_narrow_corridor_flown_both_ways_at_once():
    doc = corridor(2, 200.0)
    flown = fly(doc)
    inflated = min(o.inflated.bounds[1] for o in flown.mission.world.obstacles if o.id == "north_wall") - \
        max(o.inflated.bounds[3] for o in flown.mission.world.obstacles if o.id == "south_wall")
    assert inflated < 3 * flown.mission.safety.min_separation_m  # narrow: two lanes of traffic barely pass
    assert_safe_arrivals(flown)
    flown.assert_clearance()


def test_two_assigned_pairs_among_eight_keep_their_sight_lines_blocked():
    """missions/ring8_two_pairs.yaml: eight on a ring around a hub, v4 hiding from v0, v6 from v2."""
    mission = load_mission(ROOT / "missions" / "ring8_two_pairs.yaml")
    flown = Flown(simulate(mission))
    assert mission.sight_pairs == (("v0", "v4"), ("v2", "v6"))  # higher priority first
    assert [v.name for v in mission.vehicles if mission.carries_sightline(v.name)] == ["v4", "v6"]
    assert_safe_arrivals(flown)
    summary = flown.run.summary
    assert summary.sight_pairs == ("v0-v4", "v2-v6")
    for pair in summary.sight_pairs:
        assert summary.pairs[pair].crossing_occluded, (pair, summary.pairs[pair])
    assert summary.success_strict
    # the headline columns are the first assigned pair's
    assert summary.los_blocked_fraction == summary.pairs["v0-v4"].los_blocked_fraction


def test_two_assigned_pairs_among_eight_flown_on_the_timed_variants_space_time_plan():
    """The same ring with ``astar-bdwa-timed``: v4 is planned to hide from v0 and v6 from v2 alone
    (not from every vehicle above them), the four others for separation only; each pair's own
    certificate calls its line feasible, and the flight keeps both lines blocked."""
    mission = load_mission(ROOT / "missions" / "ring8_two_pairs.yaml").with_variant("astar-bdwa-timed")
    routes, first = flight_inputs(mission)
    plan = plan_coordinated(mission, routes, first)
    assert {n for n, b in plan.blocking.items() if b is not Blocking.NONE} == {"v0", "v4", "v6"}  # v0: first
    assert plan.hold_s == 0.0 and all(plan.planned.values())
    run, certificates = simulate_certified(mission, inputs=(routes, first))
    assert [(c.pair, c.verdict) for c in certificates] == [("v0-v4", "feasible"), ("v2-v6", "feasible")]
    flown = Flown(run)
    assert_safe_arrivals(flown)
    summary = run.summary
    for pair in ("v0-v4", "v2-v6"):
        assert summary.pairs[pair].crossing_occluded, (pair, summary.pairs[pair])
    assert summary.success_strict


def test_each_assigned_pair_gets_its_own_certificate_and_says_when_its_line_cannot_be_kept():
    """Without the hub nothing hides anyone: each pair's certificate says so, against its own
    higher vehicle's forecast; only the first vehicle in priority may be held by the rule."""
    mission = mission_from_data(ring(8, 600.0, pairs=[["v6", "v2"], ["v0", "v4"]]), "m")
    certificates = mission_certificates(mission)
    assert [(c.higher, c.lower, c.verdict) for c in certificates] == [("v2", "v6", "infeasible"),
                                                                      ("v0", "v4", "infeasible")]
    assert [c.higher_holds for c in certificates] == [False, True]
    assert "v2 is not held" in certificates[0].describe()
    assert mission_certificate(mission) == certificates[0]  # the headline: the first pair named


def test_without_an_assignment_the_papers_pair_is_scored_and_strict_success_reads_it_alone():
    flown = fly(ring(8, 600.0, hub_m=200.0))
    summary = flown.run.summary
    assert flown.mission.sight_pairs == (("v0", "v1"),)
    assert summary.sight_pairs == ("v0-v1",)
    assert summary.crossing_occluded == summary.pairs["v0-v1"].crossing_occluded
    assert summary.success_strict == (summary.success and summary.pairs["v0-v1"].crossing_occluded)
