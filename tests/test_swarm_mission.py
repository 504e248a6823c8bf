"""Sight-line pairs by assignment (``sightline.pairs``) and fleets up to 32: what a mission may
name, how it is refused, whom each planner hides from, and how runs.csv reports each pair."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from companion.bench.table import aggregate, certificate_columns, read_runs_csv, run_row, write_runs_csv
from companion.cli.bench import run as bench_cli
from companion.formations import ring
from companion.planning.coordination.certificate import hold_partner
from companion.planning.coordination.plan import departure_hold, route_forecast
from companion.planning.coordination.search import Blocking, plan_vehicle
from companion.planning.coordination.shadow import SightShadows
from companion.planning.dwa import OtherUav
from companion.planning.fleet import Neighbour, react_to
from companion.planning.flight.forecast import mission_certificates
from companion.planning.flight.headless import simulate
from companion.planning.grid import rasterise
from companion.planning.metrics import TruthGeometry
from companion.planning.routes import higher_routes, plan_routes
from companion.planning.timed_route import TimedRoute
from companion.scenarios import ScenarioConfig, ScenarioError, generate_scenario
from uav_model.mission import Mission, MissionError, mission_from_data, parse_mission

ROOT = Path(__file__).resolve().parents[1]


def _four(pairs) -> dict:
    doc = ring(4, 500.0, hub_m=150.0)
    doc["sightline"] = {"pairs": pairs}
    return doc


def _problems(doc) -> list[str]:
    with pytest.raises(MissionError) as err:
        mission_from_data(doc, "m")
    return [str(p) for p in err.value.problems]


def test_assigned_pairs_are_typed_higher_priority_first_and_name_who_hides():
    mission = mission_from_data(_four([["v2", "v0"], ["v1", "v3"]]), "m")
    assert mission.sight_pairs == (("v0", "v2"), ("v1", "v3"))
    assert [mission.hides_from(v.name) for v in mission.vehicles] == [(), (), ("v0",), ("v1",)]
    assert [mission.carries_sightline(v.name) for v in mission.vehicles] == [False, False, True, True]


def test_without_a_sightline_section_the_papers_pair_is_scored_and_every_lower_vehicle_hides():
    mission = mission_from_data(ring(4, 500.0), "m")
    assert mission.assigned_pairs is None and mission.sight_pairs == (("v0", "v1"),)
    assert [mission.hides_from(v.name) for v in mission.vehicles] == [None] * 4
    assert [mission.carries_sightline(v.name) for v in mission.vehicles] == [False, True, True, True]


@pytest.mark.parametrize("pairs, expected", [
    ([["v0", "zz"]], ["m: sightline.pairs[0][1]: unknown vehicle 'zz'; vehicles are v0, v1, v2, v3"]),
    ([["v1", "v1"]], ["m: sightline.pairs[0]: vehicle 'v1' is paired with itself; a pair names two vehicles"]),
    ([["v0", "v1"], ["v1", "v0"]], ["m: sightline.pairs[1]: duplicate pair v1-v0 (already sightline.pairs[0])"]),
    ([["v0", float("nan")]], ["m: sightline.pairs[0][1]: nan is not a finite number (NaN and infinity are refused "
                              "everywhere)"]),
    ([["v0", ["v1"]]], ["m: sightline.pairs[0][1]: expected string, got list ['v1']"]),
    ([["v0", "v1", "v2"]], ["m: sightline.pairs[0]: 3 items, more than the limit of 2"]),
    ([], ["m: sightline.pairs: 0 items; at least 1 needed"]),
])
def test_bad_pairs_are_refused_each_in_one_line(pairs, expected):
    assert _problems(_four(pairs)) == expected


def test_a_huge_name_is_echoed_in_at_most_200_characters():
    (line,) = _problems(_four([["v0", "x" * 100_000]]))
    assert "does not match" in line and len(line) < 300


def test_a_pair_naming_a_vehicle_the_schema_refused_reports_the_vehicle_only():
    doc = _four([["v0", "v3"]])
    doc["vehicles"][3]["speed_m_s"] = "fast"
    assert _problems(doc) == ["m: vehicles[3].speed_m_s: expected number, got str 'fast'"]


def _companion(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion", *args], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=cwd)


def test_validate_refuses_bad_pairs_with_exit_2_one_line_each(tmp_path):
    path = tmp_path / "pairs.yaml"
    path.write_text(yaml.safe_dump(_four([["v0", "v9"], ["v2", "v2"], ["v0", "v1"], ["v1", "v0"]])))
    proc = _companion("validate", str(path))
    assert proc.returncode == 2 and proc.stdout == "" and "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert [line.split(": ", 2)[1] for line in lines] == ["sightline.pairs[0][1]", "sightline.pairs[1]",
                                                          "sightline.pairs[3]"], proc.stderr
    assert all(line.startswith(f"{path}:") and len(line) < 300 for line in lines)


def _n(name: str, rank: int, x: float, arrived: bool = False) -> Neighbour:
    return Neighbour(name, rank, OtherUav(x, 0.0, 0.0, 0.0, arrived=arrived))


def test_an_assigned_vehicle_hides_from_its_nearest_partner_still_flying_not_the_nearest_above_it():
    near_boss, partner_far, partner_parked = _n("a", 0, 100.0), _n("c", 5, 900.0), _n("d", 6, 200.0, arrived=True)
    neighbours = [near_boss, partner_far, partner_parked]
    assert react_to(0.0, 0.0, 3, neighbours).partner is near_boss  # no assignment: the nearest above
    assert react_to(0.0, 0.0, 3, neighbours, ("c", "d")).partner is partner_far
    assert react_to(0.0, 0.0, 3, neighbours, ("d",)).partner is partner_parked  # the only one, parked
    # the separation set is every neighbour, whatever the assignment
    assert len(react_to(0.0, 0.0, 3, neighbours, ("c",)).separate_from) == 3


def test_the_lower_vehicle_of_an_assigned_pair_is_routed_against_its_partner_only():
    mission = mission_from_data(ring(6, 600.0, hub_m=200.0, pairs=[["v0", "v3"]]), "m")
    routes = plan_routes(mission)
    assert [r.vehicle for r in higher_routes(mission, routes, "v3")] == ["v0"]
    assert routes["v3"].constraint == "opposite-side"
    assert {routes[n].constraint for n in ("v1", "v2", "v4", "v5")} == {"none"}


def test_runs_csv_reports_each_assigned_pair_after_the_vehicles(tmp_path):
    mission = mission_from_data(ring(8, 600.0, hub_m=200.0, pairs=[["v0", "v4"], ["v2", "v6"]]), "m")
    run = simulate(mission)
    certificates = mission_certificates(mission)
    row = {**run_row(1, 0, "m", run.variant, run.summary.summary_dict(), wall_s=run.wall_s),
           **certificate_columns(certificates[0], certificates)}
    path = write_runs_csv([row], tmp_path / "runs.csv")
    header = path.read_text().splitlines()[0].split(",")
    cert = ["cert_whole_flight", "cert_whole_flight_hold_s", "cert_closest_approach", "cert_closest_approach_hold_s"]
    assert header[-12:] == ["v0-v4_los_blocked_fraction", "v0-v4_crossing_occluded",
                            "v2-v6_los_blocked_fraction", "v2-v6_crossing_occluded"] + [
                                f"{pair}_{key}" for pair in ("v0-v4", "v2-v6") for key in cert]
    (back,) = read_runs_csv(path)
    assert [back[f"{pair}_cert_closest_approach"] for pair in ("v0-v4", "v2-v6")] == ["feasible", "feasible"]
    assert back["v2-v6_cert_closest_approach_hold_s"] == 0.0
    assert all(back[key] == back[f"v0-v4_{key}"] for key in cert)  # the headline: the first pair's
    assert aggregate([back])[run.variant]["pair_certificates"] == {"feasible": 2, "needs-hold": 0, "infeasible": 0}
    pairs = run.summary.pairs
    assert back["sight_pairs"] == 2
    assert back["sight_pairs_occluded"] == pairs["v0-v4"].crossing_occluded + pairs["v2-v6"].crossing_occluded
    assert back["v2-v6_crossing_occluded"] is pairs["v2-v6"].crossing_occluded
    assert back["v0-v4_los_blocked_fraction"] == pytest.approx(pairs["v0-v4"].los_blocked_fraction)
    assert back["los_blocked_fraction"] == back["v0-v4_los_blocked_fraction"]  # the headline: the first pair


def test_the_generator_names_32_vehicles_and_refuses_33():
    cfg = ScenarioConfig(vehicles=32, side_m=1500.0, static_count=2, static_circumradius_m=(60.0, 120.0),
                         moving_count=0, moving_path_m=(100.0, 200.0), station_clearance_m=80.0)
    mission = generate_scenario(5, 0, cfg).mission
    names = [v.name for v in mission.by_priority]
    assert names[:26] == [chr(ord("a") + i) for i in range(26)] and names[26:] == ["a1", "b1", "c1", "d1", "e1", "f1"]
    assert len({v.goal for v in mission.vehicles}) == 32 and all(len(s) <= 3 for s in mission.stations)
    for bad in (1, 33):
        with pytest.raises(ScenarioError, match=f"vehicles: use 2 to 32 \\(got {bad}\\)"):
            ScenarioConfig(vehicles=bad)


def test_a_mission_of_33_vehicles_is_refused_at_the_schema_limit():
    doc = ring(33, 900.0)
    with pytest.raises(MissionError, match="vehicles: 33 items, more than the limit of 32"):
        parse_mission(yaml.safe_dump(doc), "m")


@pytest.mark.parametrize("count", ["1", "33"])
def test_the_bench_refuses_a_fleet_outside_2_to_32_before_flying(tmp_path, capsys, count):
    assert bench_cli(["--vehicles", count, "--scenarios", "1", "--out", str(tmp_path / "out")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == f"companion bench: vehicles: use 2 to 32 (got {count})"
    assert not (tmp_path / "out" / "runs.csv").exists()


def _wall(pairs) -> Mission:
    """a parked south of a long wall, b parked north of it, c flying west to east north of it:
    c can hide from a the whole flight, never from b."""
    doc = {"name": "wall", "area": {"x_min_m": 0, "y_min_m": 0, "x_max_m": 1000, "y_max_m": 700},
           "stations": {"A": [500, 100], "A2": [560, 100], "B": [950, 450], "B2": [950, 400],
                        "C": [200, 500], "D": [800, 500]},
           "obstacles": [{"id": "wall", "shape": "rectangle", "center": [500, 300], "width_m": 800, "height_m": 40}],
           "vehicles": [{"name": "a", "start": "A", "goal": "A2"}, {"name": "b", "start": "B", "goal": "B2"},
                        {"name": "c", "start": "C", "goal": "D"}],
           "safety": {"time_limit_s": 400}}
    if pairs is not None:
        doc["sightline"] = {"pairs": pairs}
    return mission_from_data(doc, "wall")


@pytest.mark.parametrize("pairs, kept", [(None, Blocking.NONE), ([["a", "c"]], Blocking.WHOLE_FLIGHT),
                                         ([["b", "c"]], Blocking.NONE), ([["a", "b"]], Blocking.NONE)])
def test_the_space_time_search_hides_a_vehicle_from_its_assigned_partner_only(pairs, kept):
    """Without an assignment c hides from every vehicle above it, and b sees all of c's side of
    the wall: separation only. Assigned to a, c keeps the line to a blocked the whole flight,
    the line to b open; assigned to b (or to nobody), it cannot hide."""
    mission = _wall(pairs)
    grid = rasterise(mission.world, mission.planner.grid_resolution_m)
    parked = {n: TimedRoute(n, np.array([0.0, 1.0]), np.array([mission.vehicle(n).start_enu_m] * 2)) for n in "ab"}
    route, level, step = plan_vehicle(mission, "c", (parked["a"], parked["b"]), grid, SightShadows(mission.world, grid))
    assert level is kept
    t = np.arange(0.0, route.arrival_s + step, step)
    c = route.planned_position_at(t)
    truth = TruthGeometry(mission.world)
    for name in "ab":
        other = np.broadcast_to(np.asarray(mission.vehicle(name).start_enu_m), c.shape)
        blocked = truth.sight_blocked(c[:, 0], c[:, 1], other[:, 0], other[:, 1], t)
        assert blocked.all() if name == "a" else not blocked.any()  # the wall hides c from a alone
        assert np.hypot(*(c - other).T).min() >= mission.safety.min_separation_m
    np.testing.assert_allclose(route.xy_enu_m[-1], mission.vehicle("c").goal_enu_m)


def test_validate_and_plan_report_each_assigned_pairs_certificate(tmp_path, capsys):
    from companion.cli.app import main

    mission = ROOT / "missions" / "ring8_two_pairs.yaml"
    assert main(["validate", str(mission)]) == 0
    out = capsys.readouterr().out
    assert "sight line v0-v4 blocked" in out and "(v2 is not held;" in out and "sight line v2-v6 blocked" in out
    assert main(["plan", str(mission), "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "routes.json").read_text())
    assert list(doc["occlusion_certificates"]) == ["v0-v4", "v2-v6"]
    assert doc["occlusion_certificate"] == doc["occlusion_certificates"]["v0-v4"]  # the headline
    assert doc["occlusion_certificates"]["v2-v6"]["higher_holds"] is False


@pytest.mark.parametrize("pairs, partner", [(None, "v1"), ([["v2", "v6"], ["v4", "v0"]], "v4"),
                                            ([["v2", "v6"]], None)])
def test_the_first_vehicles_departure_hold_is_for_the_first_pair_that_names_it(pairs, partner):
    """Without pairs the hold is for the second vehicle; with pairs, for the first vehicle's
    partner in the first pair naming it; in none, the first vehicle never holds."""
    doc = ring(8, 600.0, hub_m=200.0, pairs=pairs)
    doc["coordination"] = {"hold_s_max": 120.0}
    mission = mission_from_data(doc, "m")
    assert hold_partner(mission) == partner
    if partner is None:
        first = route_forecast(mission, plan_routes(mission))
        grid = rasterise(mission.world, mission.planner.grid_resolution_m)
        assert departure_hold(mission, first, grid, SightShadows(mission.world, grid)) == 0.0
