"""The first vehicle's forecast flight, replayed by the headless runner: the same flight, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from companion.planning.flight.forecast import first_forecast
from companion.planning.flight.headless import simulate
from companion.planning.timed_route import TimedRoute
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
    assert all(read_back) != contact  # after a contact the planner decides by itself
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


def test_the_timed_first_vehicle_is_not_read_back():
    """In flight it tracks its forecast (held by its departure hold), which its forecast, flown
    before there was one, could not: another flight, decided again tick by tick."""
    mission, first, replayed, flown = _fly_both(7, 1, "astar-bdwa-timed")
    top = mission.by_priority[0].name
    assert not any(r is s for r, s in zip(replayed.ticks[top], first.flight.results))
    for name in replayed.tracks:
        assert _decisions(replayed, name) == _decisions(flown, name)
