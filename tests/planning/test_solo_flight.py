"""The first vehicle's forecast flight, replayed by the headless runner: the same flight, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from companion.planning.flight.forecast import first_forecast
from companion.planning.flight.headless import simulate
from companion.planning.flight.replay import pose_of
from companion.planning.timed_route import TimedRoute
from companion.planning.vehicle_planner import PACE_LEAD_M
from companion.scenarios import ScenarioConfig, generate_scenario


def _decisions(run, name):
    return [(r.command, r.arrived, r.goal_index, r.hold_reason, r.escape_reason, r.recovery_reason)
            for r in run.ticks[name]]


def _fly_both(seed, index, variant):
    s = generate_scenario(seed, index, ScenarioConfig())
    mission = s.mission.with_variant(variant)
    first = first_forecast(mission, s.routes)
    plain = TimedRoute(first.vehicle, first.t_s, first.xy_enu_m)  # the same forecast, without its flight
    return mission, first, simulate(mission, routes=s.routes, first=first), simulate(mission, routes=s.routes, first=plain)


@pytest.mark.parametrize("seed, index, variant, contact", [
    (7, 0, "astar-bdwa", False),        # the two never come within reach: the first is read back throughout
    (7, 7, "astar-bdwa", True),         # they do, at tick 451: the planner catches up and decides on
    (2026, 1, "bdwa", True),
    (2026, 6, "astar-bdwa-timed", True),  # the same with a timed route, its pace and the schedule clocks
    (7, 1, "astar-bdwa-timed", False),
])
def test_a_replayed_flight_is_the_flight(seed, index, variant, contact):
    mission, first, replayed, flown = _fly_both(seed, index, variant)
    top = mission.by_priority[0].name
    for name in replayed.tracks:
        assert np.array_equal(replayed.tracks[name].x_m, flown.tracks[name].x_m)
        assert np.array_equal(replayed.tracks[name].y_m, flown.tracks[name].y_m)
        assert _decisions(replayed, name) == _decisions(flown, name)
    assert replayed.summary.success == flown.summary.success
    assert replayed.summary.planner == flown.summary.planner
    read_back = [r is s for r, s in zip(replayed.ticks[top], first.flight.results)]
    assert read_back[0]  # the first tick is read back, not decided again
    assert all(read_back) != contact  # within reach of another vehicle the planner decides by itself
    if contact:  # and out of reach again, still where it flew alone, it is read back again
        assert read_back[-1] and read_back.index(False) < len(read_back) - 1
    assert not any(r is s for r, s in zip(flown.ticks[top], first.flight.results))


@pytest.mark.parametrize("forecast_by, flown_by, replayed", [
    ("astar-bdwa-nosparse", "astar-bdwa", False),  # another variant's forecast: another flight
    ("bdwa", "dwa", True),  # the first flies without the sightline term: one flight for both
])
def test_a_forecast_is_replayed_only_by_a_variant_that_flies_the_first_vehicle_alike(forecast_by, flown_by, replayed):
    s = generate_scenario(7, 0, ScenarioConfig())
    first = first_forecast(s.mission.with_variant(forecast_by), s.routes)
    mission = s.mission.with_variant(flown_by)
    run = simulate(mission, routes=s.routes, first=first)
    assert (run.ticks[mission.by_priority[0].name][0] is first.flight.results[0]) == replayed


def test_the_first_vehicle_flies_its_forecast_in_a_timed_flight():
    """It tracks what its forecast tracked (its route at cruise), paced by the forecast: without
    a hold and out of reach of the others, the forecast is its flight, read back tick by tick."""
    mission, first, replayed, _ = _fly_both(7, 1, "astar-bdwa-timed")
    top = mission.by_priority[0].name
    track = replayed.tracks[top]
    kept = [pose_of(state) for state in first.flight.states]
    assert len(track.x_m) == len(kept)
    assert np.array_equal(track.x_m, [p.x_m for p in kept]) and np.array_equal(track.y_m, [p.y_m for p in kept])
    assert all(r is s for r, s in zip(replayed.ticks[top], first.flight.results))


def test_a_paced_first_vehicle_never_runs_ahead_of_its_forecast():
    """A forecast slower than the vehicle flies (PX4 turns faster than the plant it was flown
    on): the first vehicle is held back to it, within PACE_LEAD_M and a tick's braking, and
    arrives when it does; the lower vehicles' plans count on that."""
    s = generate_scenario(7, 1, ScenarioConfig())
    mission = s.mission.with_variant("astar-bdwa-timed")
    first = first_forecast(mission, s.routes)
    slow = TimedRoute(first.vehicle, first.t_s * 1.25, first.xy_enu_m)  # a quarter slower throughout
    run = simulate(mission, routes=s.routes, first=slow)
    top = mission.by_priority[0].name
    track = run.tracks[top]
    assert run.summary.success
    lead = slow.lead_m(np.column_stack([track.x_m, track.y_m]), track.t_s)
    assert lead.max() <= PACE_LEAD_M + 10.0  # cruise is 10 m/s: a second's worth at most
    assert track.t_s[-1] >= slow.t_s[-1] - 5.0
    alone = simulate(mission, routes=s.routes, first=first).tracks[top]  # paced by its own forecast
    assert track.t_s[-1] > alone.t_s[-1] + 0.15 * alone.t_s[-1]
