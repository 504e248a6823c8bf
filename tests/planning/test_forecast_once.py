"""The first vehicle's forecast is flown once, and what plans and certifies is given it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uav_model.mission import load_mission
from companion.planning.coordination.plan import route_forecast
from companion.planning.flight import forecast as forecast_module
from companion.planning.flight.fleet_setup import build_fleet
from companion.planning.flight.replay import forecast_key
from companion.planning.flight.headless import simulate_certified
from companion.planning.routes import plan_routes

SMALL = Path(__file__).resolve().parents[2] / "missions" / "small_reference.yaml"


@pytest.fixture(scope="module")
def timed():
    mission = load_mission(SMALL).with_variant("astar-bdwa-timed")
    return mission, plan_routes(mission)


def test_the_plan_flies_against_the_forecast_it_is_given(timed):
    mission, routes = timed
    first = route_forecast(mission, routes)  # not the flown one the mission asks for
    fleet = build_fleet(mission, routes, first=first)
    top = mission.by_priority[0].name
    assert np.array_equal(fleet.timed[top].path_xy, first.path_xy)


def test_a_timed_fleet_without_the_forecast_says_what_it_needs(timed):
    mission, routes = timed
    with pytest.raises(ValueError, match="pass first"):
        build_fleet(mission, routes)


@pytest.fixture
def flights(monkeypatch):
    """The vehicles the flown forecast flies, in order, as this test runs."""
    flown = []
    real = forecast_module.flown_forecast

    def counted(*args, **kwargs):
        flown.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(forecast_module, "flown_forecast", counted)
    return flown


def test_a_timed_run_and_its_certificate_fly_the_first_vehicle_once(timed, flights):
    mission, _ = timed
    run, certificates = simulate_certified(mission)
    assert flights == [mission.by_priority[0].name]
    assert len(certificates) == 1 and run.summary.duration_s > 0


def test_companion_simulate_flies_the_first_vehicle_alone_once(flights, tmp_path, capsys):
    """The warm-up before the clock and the timed flight share the forecast: no second flight."""
    from companion.cli.app import main

    assert main(["simulate", str(SMALL), "--variant", "astar-bdwa-timed", "--out", str(tmp_path / "out")]) in (0, 1)
    assert flights == [load_mission(SMALL).by_priority[0].name]
    assert "occlusion certificate" in capsys.readouterr().out


def test_variants_that_fly_the_first_vehicle_alike_share_its_forecast():
    """The first in priority flies without the sightline term: bdwa's and dwa's forecasts are one
    flight (the bench flies it once for both), and every other variant's is its own."""
    mission = load_mission(SMALL)
    keys = {v: forecast_key(mission.with_variant(v))
            for v in ("astar-bdwa", "astar-bdwa-nosparse", "bdwa", "dwa", "astar-bdwa-timed")}
    assert keys["bdwa"] == keys["dwa"]
    assert len(set(keys.values())) == 4
    routes = plan_routes(mission)
    bdwa, dwa = (forecast_module.first_forecast(mission.with_variant(v), routes) for v in ("bdwa", "dwa"))
    assert np.array_equal(bdwa.t_s, dwa.t_s) and np.array_equal(bdwa.xy_enu_m, dwa.xy_enu_m)
