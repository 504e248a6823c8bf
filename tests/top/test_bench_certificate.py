"""The bench's occlusion-certificate columns: one verdict per question and scenario, under the
mission's rule, the same in every run of a scenario, and counted in the summary and the tables."""

from __future__ import annotations

import pytest

from companion.bench import aggregate, read_runs_csv
from companion.bench.execute import ScenarioTask, run_scenario
from companion.bench.table import certificate_columns, format_table, markdown_table, write_runs_csv
from companion.planning.coordination.certificate import OcclusionCertificate, certify
from companion.planning.flight.forecast import first_forecast
from companion.scenarios import ScenarioConfig, generate_scenario

SMALL = {"side_m": 1000.0, "static_count": 2, "static_circumradius_m": [40.0, 90.0],
         "moving_count": 1, "moving_radius_m": [20.0, 30.0], "moving_path_m": [150.0, 300.0],
         "moving_speed_m_s": [2.0, 4.0], "station_clearance_m": 100.0}


def _cert(whole: float | None, near: float | None, limit: float = 0.0) -> OcclusionCertificate:
    return OcclusionCertificate(
        higher="a", lower="b", hold_s_max=limit, step_s=5.0, resolution_m=10.0,
        whole_flight=whole is not None and whole <= limit, closest_approach=near is not None and near <= limit,
        whole_flight_min_hold_s=whole, closest_approach_min_hold_s=near, searched_hold_s=300.0)


@pytest.mark.parametrize("whole, near, limit, verdicts", [
    (0.0, 0.0, 0.0, ("feasible", "feasible")),
    (None, 0.0, 0.0, ("infeasible", "feasible")),
    (160.0, 55.0, 0.0, ("needs-hold", "needs-hold")),
    (160.0, 55.0, 60.0, ("needs-hold", "feasible")),  # the mission's rule allows a 60 s hold
    (None, None, 0.0, ("infeasible", "infeasible")),
])
def test_a_verdict_follows_the_least_hold_and_the_missions_rule(whole, near, limit, verdicts):
    cols = certificate_columns(_cert(whole, near, limit))
    assert (cols["cert_whole_flight"], cols["cert_closest_approach"]) == verdicts
    assert (cols["cert_whole_flight_hold_s"], cols["cert_closest_approach_hold_s"]) == (whole, near)
    assert certificate_columns(None) == {}


def _row(index, variant, strict, cert_near, b_ratio, success=True):
    return {"seed": 1, "index": index, "scenario": f"s{index}", "variant": variant, "success": success,
            "success_strict": strict, "reason": None if success else "timeout", "planner_ms_per_tick": 1.0,
            "wall_s": 2.0, "a_arrived": success, "a_flight_time_s": 400.0, "a_ratio": 1.0,
            "b_arrived": success, "b_flight_time_s": 400.0 * b_ratio, "b_ratio": b_ratio,
            "cert_whole_flight": "infeasible", "cert_whole_flight_hold_s": None,
            "cert_closest_approach": cert_near, "cert_closest_approach_hold_s": {"feasible": 0.0}.get(cert_near, 50.0)}


def test_the_summary_counts_verdicts_and_judges_only_feasible_scenarios(tmp_path):
    rows = [_row(0, "t", True, "feasible", 1.1), _row(1, "t", False, "feasible", 1.3),
            _row(2, "t", False, "needs-hold", 2.0), _row(3, "t", False, "feasible", 9.0, success=False)]
    s = aggregate(rows)["t"]
    assert s["certificate"]["closest_approach"] == {"feasible": 3, "needs-hold": 1, "infeasible": 0}
    assert s["certificate"]["whole_flight"] == {"feasible": 0, "needs-hold": 0, "infeasible": 4}
    assert s["strict_where_feasible"] == {"scenarios": 3, "strict": 1, "rate": pytest.approx(1 / 3, abs=1e-4)}
    assert s["ratio_to_bound_no_hold"]["b"]["mean"] == pytest.approx(1.2)  # successes needing no hold only
    write_runs_csv(rows, tmp_path / "runs.csv")
    assert aggregate(read_runs_csv(tmp_path / "runs.csv")) == aggregate(rows)
    assert "3 / 1 / 0" in markdown_table(aggregate(rows)) and "1/3 (33.3 %)" in markdown_table(aggregate(rows))
    assert "closest approach 3 / 1 / 0" in format_table(aggregate(rows))


def test_every_run_carries_the_certificate_of_the_forecast_its_own_variant_flies():
    config = ScenarioConfig.from_mapping(SMALL)
    variants = ("astar-bdwa", "bdwa", "astar-bdwa-timed")
    rows = run_scenario(ScenarioTask(7, 0, variants, config)).rows
    scenario = generate_scenario(7, 0, config)
    forecasts = {}
    for variant, row in zip(variants, rows):
        mission = scenario.mission.with_variant(variant)
        forecasts[variant] = first = first_forecast(mission, scenario.routes)
        expected = certificate_columns(certify(mission, first))
        assert expected["cert_closest_approach"] in ("feasible", "needs-hold", "infeasible")
        assert row["variant"] == variant and {k: row[k] for k in expected} == expected
    # Each variant flies the first vehicle its own way: one certificate for all would judge
    # a flight the other rows do not fly.
    ends = {v: float(f.t_s[-1]) for v, f in forecasts.items()}
    assert len(set(ends.values())) > 1, ends


def test_without_the_certificate_the_runs_are_the_same_and_its_columns_empty():
    config = ScenarioConfig.from_mapping(SMALL)
    with_cert = run_scenario(ScenarioTask(7, 0, ("astar-bdwa",), config)).rows
    without = run_scenario(ScenarioTask(7, 0, ("astar-bdwa",), config, certificate=False)).rows
    timing = {"wall_s", "planner_ms_per_tick"}
    for a, b in zip(with_cert, without):
        assert not any(k.startswith("cert_") for k in b)
        assert {k: v for k, v in a.items() if not k.startswith("cert_") and k not in timing} == \
               {k: v for k, v in b.items() if k not in timing}
