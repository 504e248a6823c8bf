"""The earliest path whose closest approach is blocked, for one D and over the ladder of D
(:mod:`companion.planning.coordination.nearpath`): it agrees with a brute-force search on small worlds, its
paths keep the rule they were planned under, and the ladder never arrives later than D* alone."""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from uav_model.mission import load_mission
from companion.planning.coordination.search import Blocking, _near_witness, near_margin_m, plan_vehicle, problem_for
from companion.planning.grid import rasterise
from companion.planning.coordination.nearpath import best_near, earliest_near, ladder_m2
from companion.planning.routes import plan_routes
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.timed import forecast
from spacetime_bruteforce import BruteForce
from test_certificate import small_missions

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"


def _problem(mission, routes, hold_s: float = 0.0):
    higher, lower = mission.by_priority[0], mission.by_priority[1]
    grid = rasterise(mission.world, mission.planner.grid_resolution_m)
    others = (forecast(higher.name, routes[higher.name].sparse_enu_m, higher.speed_m_s, hold_s),)
    return problem_for(mission, grid, SightShadows(mission.world, grid), lower.name, others, higher.speed_m_s)


def _check_path(brute: BruteForce, cells, near_m: float, margin_m: float, tol_m: float = 0.0) -> None:
    """Every step a legal move, every state separated, no open state within near + margin, and a
    blocked one within near (``tol_m``: for a near that is a state's own distance, rounded)."""
    witnessed = False
    for k, cell in enumerate(cells):
        if k:
            assert cell in brute.next(cells[k - 1]), (k, cells[k - 1], cell)
        far, blocked, d2 = brute._state(cell, k, 0.0)
        d = math.sqrt(d2)
        assert far and (blocked or d > near_m + margin_m - tol_m), (k, cell, blocked, d)
        witnessed |= blocked and d <= near_m + tol_m
    assert witnessed and cells[0] == brute.start and cells[-1] == brute.goal


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(small_missions(), st.floats(0.0, 120.0), st.sampled_from([0.0, 15.5]))
def test_earliest_near_agrees_with_brute_force(case, near_m, margin_m):
    mission, routes = case
    brute = BruteForce(mission, routes)
    expected = brute.earliest_near(0.0, near_m, margin_m)
    found = earliest_near(_problem(mission, routes), near_m ** 2, margin_m)
    event("a path" if expected is not None else "no path")
    assert (None if found is None else found[0]) == expected
    if found is not None:
        arrive, cells = found
        assert len(cells) == arrive + 1
        _check_path(brute, cells, near_m, margin_m)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(small_missions())
def test_the_ladder_keeps_the_rule_and_never_arrives_later_than_d_star(case):
    mission, routes = case
    problem = _problem(mission, routes)
    witness = _near_witness(problem)
    if witness is None:
        event("infeasible")
        return
    near2 = witness[-1]
    at_star = earliest_near(problem, near2, 0.0)
    assert at_star is not None  # the witness's own path is one of them
    d2, cells = best_near(problem, near2, 0.0)
    assert d2 in ladder_m2(near2, 0.0, 6) and len(cells) - 1 <= at_star[0]
    _check_path(BruteForce(mission, routes), cells, math.sqrt(d2), 0.0, 1e-6)


def test_reference_with_a_hold_plans_b_earlier_than_the_nearest_witness_does():
    """The paper's reference, a held 75 s (the closest approach is feasible, the whole flight is
    not): the plan over the ladder arrives no later than the best path at D* alone."""
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    problem = _problem(mission, routes, 75.0)
    # as plan_vehicle: with the margin first, else without
    margin, witness = next((m, w) for m in (near_margin_m(mission, "b", 10.0), 0.0)
                           for w in [_near_witness(problem, m)] if w is not None)
    at_star = earliest_near(problem, witness[-1], margin)
    grid = problem.grid
    found = plan_vehicle(mission, "b", problem.others, grid, SightShadows(mission.world, grid))
    assert found is not None
    timed, level, step_s = found
    assert level is Blocking.CLOSEST_APPROACH
    assert timed.arrival_s <= at_star[0] * step_s + 1e-6
    print(f"margin {margin:.1f} m: D* alone arrives at {at_star[0] * step_s:.1f} s, the ladder at {timed.arrival_s:.1f} s")
