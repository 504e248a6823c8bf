"""The space-time search's shortcuts give the answers of the masks they stand for, on real plans:
the allowed mask built in one pass, the goal cell tested alone (``stay_from``), the per-step
``blocked_by_all`` kept, the masks computed only on the tiles a search reaches, the states on a
full path found from the forward sets alone (``on_path``)."""

import math

import numpy as np
import pytest

from companion.planning.coordination import bitgrid
from companion.planning.coordination.plan import plan_coordinated, route_forecast
from companion.planning.coordination.search import Blocking, problem_for
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.spacetime import SightRule, allowed_table, forward, on_path, stay_from
from companion.planning.grid import rasterise
from companion.scenarios import ScenarioConfig, generate_scenario


@pytest.fixture(scope="module")
def makers():
    """The lowest vehicle of a generated 4-vehicle scenario against the plans above it, before
    flight and as a re-plan from mid-route at t = 100 s: each problem made afresh by a call."""
    sc = generate_scenario(4242, 0, ScenarioConfig(vehicles=4))
    mission, routes = sc.mission, sc.routes
    grid = rasterise(mission.world, mission.planner.grid_resolution_m)
    shadows = SightShadows(mission.world, grid)
    plan = plan_coordinated(mission, routes, route_forecast(mission, routes), hold_s=0.0, grid=grid, shadows=shadows)
    order = [v.name for v in mission.by_priority]
    low, above = order[-1], tuple(plan.timed[n] for n in order[:-1])
    fastest = max(mission.vehicle(n).speed_m_s for n in order[:-1])
    mid = tuple(plan.timed[low].planned_position_at(np.array([100.0]))[0])
    return [lambda: problem_for(mission, grid, shadows, low, above, fastest, {}),
            lambda: problem_for(mission, grid, shadows, low, above, fastest, {}, from_xy=mid, t0_s=100.0)]


@pytest.fixture(scope="module")
def problems(makers):
    return [make() for make in makers]


def _reference(p, k, rule, near2):
    """allowed(k) mask by mask, as the rules read."""
    ok = p.free_bits.copy()
    for xy in p.positions(k):
        ok &= bitgrid.farther(p._xs, p._ys, xy, p.model.min_distance_m ** 2, strict=False)
    if rule is SightRule.FREE:
        return ok
    for xy in p.sight_positions(k):
        shadow = bitgrid.pack(p.shadows.blocked_from(xy))
        ok &= shadow if rule is SightRule.BLOCKED else shadow | bitgrid.farther(p._xs, p._ys, xy, near2)
    return ok


def _rules(p):
    """Every rule, BLOCKED_WHEN_NEAR at distances below the separation, at it, and beyond."""
    sep2 = p.model.min_distance_m ** 2
    return [(SightRule.FREE, math.inf), (SightRule.BLOCKED, math.inf)] + [
        (SightRule.BLOCKED_WHEN_NEAR, d2) for d2 in (0.0, 0.5 * sep2, sep2, 4.0 * sep2, 25.0 * sep2, math.inf)]


def test_allowed_masks_and_the_goal_test_equal_the_masks_one_by_one(problems):
    for p in problems:
        for rule, near2 in _rules(p):
            for k in range(0, p.settled + 2):
                got = p.allowed(k, rule, near2)
                assert np.array_equal(got, _reference(p, k, rule, near2)), (rule, near2, k)
                assert p.goal_allowed(k, rule, near2) == p.has(got, p.goal)


def test_stay_from_by_the_goal_cell_equals_it_by_the_whole_masks(problems):
    seen = set()
    for p in problems:
        for rule, near2 in _rules(p):
            table = allowed_table(p, rule, near2)
            ok = np.array([p.has(_reference(p, k, rule, near2), p.goal) for k in range(len(table))])
            bad = np.flatnonzero(~ok)
            want = None if not ok[-1] else (int(bad[-1]) + 1 if bad.size else 0)
            assert stay_from(p, table) == want
            seen.add(want is None)
    assert seen == {True, False}  # both answers occur: the test can fail either way


def _fresh_blocked(p, k):
    want = p.free_bits.copy()
    for xy in p.sight_positions(k):
        want &= bitgrid.pack(p.shadows.blocked_from(xy))
    return want


def test_blocked_by_all_kept_per_step_equals_a_fresh_one(problems):
    for p in problems:
        for k in list(range(p.settled + 3)) * 2:  # the second round reads what the first kept
            assert np.array_equal(p.blocked_by_all(k), _fresh_blocked(p, k))


class _Forgetful(dict):
    """A table cache that keeps nothing: every allowed_table call builds its table afresh."""

    def __setitem__(self, key, value):
        pass


def test_closest_approach_plans_are_the_same_with_the_tables_kept_or_rebuilt(problems):
    from companion.planning.coordination.search import solve
    for p in problems:
        kept = solve(p, Blocking.CLOSEST_APPROACH, 20.0)
        assert kept is not None and len(p.tables) >= 2
        p.tables = _Forgetful()
        try:
            rebuilt = solve(p, Blocking.CLOSEST_APPROACH, 20.0)
        finally:
            p.tables = {}
        assert rebuilt is not None and rebuilt.cells == kept.cells


def test_forward_sets_on_the_tiles_reached_and_the_states_on_a_path_equal_those_of_whole_masks(makers):
    """Forward sets from the start, grown on masks computed only where the set can reach, are the
    sets grown on whole masks; ``on_path`` (F[k] & B[k] without B) is F[k] & B[k] with B grown
    back from the goal on whole masks; the blocked cells read on those sets are the whole mask's."""
    seen = set()
    for make in makers:
        for rule, near2 in _rules(make()):
            p = make()  # nothing computed yet: every mask on the tiles asked for
            table = allowed_table(p, rule, near2)
            start = table.at(0, p.cell_mask(p.start))
            if not start.any():
                continue
            fwd = forward(p, table, start, 0)
            ref = [_reference(p, k, rule, near2) for k in range(p.settled + 1)]
            ref += [ref[-1]] * (p.horizon - p.settled)
            want = [p.cell_mask(p.start) & ref[0]]
            for k in range(1, p.horizon + 1):
                want.append(p.grow(want[-1]) & ref[k])
            assert all(np.array_equal(fwd[k], want[k]) for k in range(p.horizon + 1)), (rule, near2)
            back = [p.cell_mask(p.goal) & ref[p.horizon]]
            for k in range(p.horizon - 1, -1, -1):
                back.append(p.grow(back[-1]) & ref[k])
            back.reverse()
            path = on_path(p, fwd)
            seen.add((rule, bool(path[0].any())))
            for k in range(p.horizon + 1):
                assert np.array_equal(path[k], want[k] & back[k]), (rule, near2, k)
                blocked = p.blocked_by_all(k, path[k])
                assert np.array_equal(blocked, path[k] & _fresh_blocked(p, k))
    assert {(SightRule.FREE, True), (SightRule.BLOCKED_WHEN_NEAR, True)} <= seen  # sets on a path, not only empty ones


def test_plans_are_the_same_on_the_numpy_paths():
    """Without the compiled kernels (no numba: whole masks at once, the numpy tile maps, growth
    and backtracking) the plans are the same, closest-approach ones too."""
    from companion.planning.coordination import backtrack, shadow, tiles
    sc = generate_scenario(7, 9, ScenarioConfig())
    mission, routes = sc.mission, sc.routes
    first = route_forecast(mission, routes)
    compiled = plan_coordinated(mission, routes, first, hold_s=0.0)
    kernels = [(shadow, "_blocked_jit"), (backtrack, "_step_back_jit")]
    kernels += [(bitgrid, n) for n in ("_farther_jit", "_nearest_jit", "_grow_jit", "_dilate_within_jit",
                                       "_allowed_jit", "_within_any_jit")]
    kernels += [(tiles, n) for n in ("_tiles_of_jit", "_spills_jit", "_missing_jit")]
    saved = [getattr(m, n) for m, n in kernels]
    for m, n in kernels:
        setattr(m, n, None)
    try:
        plain = plan_coordinated(mission, routes, first, hold_s=0.0)
    finally:
        for (m, n), kernel in zip(kernels, saved):
            setattr(m, n, kernel)
    assert set(compiled.blocking.values()) >= {Blocking.CLOSEST_APPROACH}
    assert plain.blocking == compiled.blocking and plain.planned == compiled.planned
    for name, route in compiled.timed.items():
        assert np.array_equal(plain.timed[name].t_s, route.t_s) and np.array_equal(plain.timed[name].xy_enu_m, route.xy_enu_m)
