"""The space-time search of one lower vehicle against the forecasts of the vehicles above it.

Every vehicle but the first in priority is planned on the space-time graph of :mod:`spacetime`
against the forecasts of all vehicles above it (:mod:`plan`), the strictest rule first:

    Blocking.WHOLE_FLIGHT       the sight line to every higher vehicle it hides from crosses a
                                true obstacle at every step instant, from departure until
                                everyone has arrived
    Blocking.CLOSEST_APPROACH   the sight line is blocked at the closest approach: at a blocked
                                instant no farther than any instant at which it is open (exact
                                for two vehicles; with more it holds for one pair)
    Blocking.NONE               separation only (the line is not kept blocked)

and, when even separation cannot be planned, None (the caller flies its route at cruise). A*
cells of the inflated obstacles keep static clearance throughout. A vehicle hides from every
vehicle above it, or, when the mission assigns sight-line pairs, from its assigned partners
above it only (``Mission.hides_from``); one that hides from none of them is planned for
separation only (Blocking.NONE). Separation is kept from every vehicle above it.

Closest approach: a path has its closest approach blocked iff some D has every open instant
farther than D and some blocked instant within D. Forbidding open instants within D shrinks the
reachable set R(D) as D grows, so g(D) = the least distance of a blocked state in R(D) grows
too; iterating D <- g(D) from 0 never passes a feasible D, and stops at one (g(D) <= D) or at
an empty R: infeasible. The plan is then the earliest-arriving path over a ladder of D from D*
on (:mod:`nearpath`), not only the path through the nearest blocked state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.budget import Budget
from companion.planning.grid import OccupancyGrid
from companion.planning.coordination.backtrack import backtrack
from companion.planning.coordination.nearpath import best_near
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.spacetime import (AllowedTable, Layers, SightRule, SpaceTimeProblem, allowed_table,
                                                       earliest_arrival, forward, on_path, stay_from,
                                                       step_model)
from companion.planning.timed_route import TimedRoute

if TYPE_CHECKING:
    from uav_model.mission import Mission

_MAX_NEAR_ROUNDS = 200  # D <- g(D) rounds; each raises D to a new state distance
NEAR_RUNGS = 6  # distances D tried from D* on (nearpath.ladder_m2: up to D* + 16 margins); 4 and 6 compared on tuning seeds


class Blocking(Enum):
    """How well a vehicle's plan keeps its sight lines to the vehicles above it blocked."""

    WHOLE_FLIGHT = "whole-flight"
    CLOSEST_APPROACH = "closest-approach"
    NONE = "none"


@dataclass(frozen=True, eq=False)
class Solution:
    """One vehicle's space-time path: a cell per step (step 0 is departure time 0)."""

    cells: list[tuple[int, int]]
    step_s: float
    blocking: Blocking
    t0_s: float = 0.0  # mission time of step 0


def solve(problem: SpaceTimeProblem, blocking: Blocking, margin_m: float = 0.0) -> Solution | None:
    """The earliest-arriving path under ``blocking``, or None when there is none. ``margin_m``
    (closest approach only): the line must also be blocked wherever the distance is within
    this much of the closest approach, so that the closest approach of the flown (continuous,
    imperfectly tracked) paths falls on a blocked stretch too."""
    if blocking is Blocking.CLOSEST_APPROACH:
        return _solve_near(problem, margin_m)
    found = _earliest(problem, blocking)
    if found is None:
        return None
    layers, arrive = found
    return Solution(backtrack(problem, layers, problem.goal, arrive, 0), problem.model.step_s, blocking, problem.t0_s)


def _earliest(problem: SpaceTimeProblem, blocking: Blocking) -> tuple[Layers, int] | None:
    """Forward layers up to the earliest arrival under a per-instant rule, and that step."""
    rule = SightRule.BLOCKED if blocking is Blocking.WHOLE_FLIGHT else SightRule.FREE
    table = allowed_table(problem, rule)
    start = table.at(0, problem.cell_mask(problem.start))
    if not start.any():
        return None
    layers = forward(problem, table, start, 0, stop_at_arrival=True)
    stay = None if layers.empty else stay_from(problem, table)
    arrive = None if stay is None else earliest_arrival(problem, layers, stay)
    return None if arrive is None else (layers, arrive)


def feasible(problem: SpaceTimeProblem, blocking: Blocking, margin_m: float = 0.0) -> bool:
    """Whether any path exists under ``blocking`` (no path is built); ``margin_m`` as for
    :func:`solve`."""
    if blocking is Blocking.CLOSEST_APPROACH:
        return _near_witness(problem, margin_m) is not None
    return _earliest(problem, blocking) is not None


def _near_witness(problem: SpaceTimeProblem, margin_m: float = 0.0) -> tuple[AllowedTable, Layers, tuple[int, int], int, float] | None:
    """(allowed table, forward layers, s* cell, s* step, D^2) for the D <- g(D) fixed point, or None."""
    near2 = 0.0  # D^2: squared throughout, so that a tie between two states stays a tie
    for _ in range(_MAX_NEAR_ROUNDS):
        table = allowed_table(problem, SightRule.BLOCKED_WHEN_NEAR,
                              (math.sqrt(near2) + margin_m) ** 2 if margin_m else near2)
        start = table.at(0, problem.cell_mask(problem.start))
        if not start.any():
            return None
        fwd = forward(problem, table, start, 0)
        stay = None if fwd.empty else stay_from(problem, table)
        if stay is None or earliest_arrival(problem, fwd, stay) is None:
            return None  # no path at all: no need for the backward pass
        best = _closest_blocked(problem, on_path(problem, fwd))
        if best is None:
            return None
        d2, cell, k = best
        if d2 <= near2:
            return table, fwd, cell, k, near2
        near2 = d2
    raise RuntimeError(f"closest-approach search did not settle in {_MAX_NEAR_ROUNDS} rounds")


def _closest_blocked(problem: SpaceTimeProblem, path: Layers) -> tuple[float, tuple[int, int], int] | None:
    """The least squared distance to the nearest higher vehicle it hides from over states on a full
    path (``path``: :func:`spacetime.on_path`) that are blocked from all of those: (squared
    distance, cell, step), earliest step on ties. Between its head and its tail nothing changes
    (the set, nor the vehicles' positions, fixed from ``settled`` on): the first such step stands for all."""
    steps = sorted(set(range(len(path.head) + 1)) | set(range(problem.horizon - len(path.tail), problem.horizon + 1)))
    best = None
    for k in steps:
        if k > problem.horizon:
            continue
        states = problem.blocked_by_all(k, path[k])
        if not states.any():
            continue
        d2, cell = problem.nearest_d2(k, states)
        if best is None or d2 < best[0]:
            best = (d2, cell, k)
    return best


def _solve_near(problem: SpaceTimeProblem, margin_m: float) -> Solution | None:
    """The earliest-arriving path over the ladder of D from the least feasible D*
    (:func:`nearpath.best_near`), rather than the path through the one witness state at D*,
    the nearest blocked state, which can make b wait minutes for it (plans up to 1.7 x bound
    where the ladder stays near 1.2)."""
    witness = _near_witness(problem, margin_m)
    if witness is None:
        return None
    found = best_near(problem, witness[-1], margin_m, NEAR_RUNGS)
    if found is None:  # the witness's own path is one at D*
        raise AssertionError("closest-approach witness without a path")
    return Solution(found[1], problem.model.step_s, Blocking.CLOSEST_APPROACH, problem.t0_s)


def to_timed(name: str, grid: OccupancyGrid, solution: Solution, start_xy, goal_xy) -> TimedRoute:
    """The solution's cell centres at their step times (exact stations at the ends), keeping
    only the points where speed or heading changes."""
    xs, ys = grid.cell_centres()
    xy = np.array([(xs[ix], ys[iy]) for ix, iy in solution.cells], dtype=float)
    same_start = np.all(np.array(solution.cells) == solution.cells[0], axis=1)
    xy[np.cumprod(same_start).astype(bool)] = start_xy
    same_goal = np.all(np.array(solution.cells) == solution.cells[-1], axis=1)
    xy[np.cumprod(same_goal[::-1]).astype(bool)[::-1]] = goal_xy
    t = solution.t0_s + np.arange(len(xy)) * solution.step_s
    keep = np.ones(len(xy), dtype=bool)
    if len(xy) > 2:
        mid = (xy[:-2] + xy[2:]) / 2.0  # equal steps: a point on a constant-velocity run is the mean
        keep[1:-1] = np.hypot(*(xy[1:-1] - mid).T) > 1e-6
    return TimedRoute(name, t[keep], xy[keep])


def problem_for(mission: "Mission", grid: OccupancyGrid, shadows: SightShadows, name: str,
                others: tuple[TimedRoute, ...], fastest_other_m_s: float, memo: dict | None = None, *,
                from_xy: tuple[float, float] | None = None, t0_s: float = 0.0,
                budget: Budget | None = None, pair_alone: bool = False) -> SpaceTimeProblem:
    """Vehicle ``name`` against ``others``, hiding from those the mission has it hide from (all of
    them, or its assigned partners among them: ``Mission.hides_from``; ``pair_alone``: from every
    one of ``others``, the higher vehicle of a pair judged alone); ``memo`` shares masks between
    problems on ``grid``.
    A re-plan starts at ``from_xy`` at mission time ``t0_s`` (default: its station at 0).
    ``budget``: charged by the searches on the problem (:mod:`budget`)."""
    v = mission.vehicle(name)
    c = mission.coordination
    model = step_model(grid.resolution_m, v.speed_m_s, c.step_s, mission.safety.min_separation_m, fastest_other_m_s)
    start = v.start_enu_m if from_xy is None else (float(from_xy[0]), float(from_xy[1]))
    return SpaceTimeProblem(grid, shadows, model, start, v.goal_enu_m, others,
                            mission.safety.time_limit_s, memo, t0_s, budget,
                            None if pair_alone else mission.hides_from(name))


def plan_vehicle(mission: "Mission", name: str, others: tuple[TimedRoute, ...], grid: OccupancyGrid,
                 shadows: SightShadows, memo: dict | None = None, *, from_xy: tuple[float, float] | None = None,
                 t0_s: float = 0.0) -> tuple[TimedRoute, Blocking, float] | None:
    """One lower-priority vehicle against ``others`` (forecasts of the vehicles above it), the
    strictest rule first: (timed route, rule kept, step s), or None when not even separation can
    be planned. A vehicle that hides from none of ``others`` (``Mission.hides_from``) is planned
    for separation only. Before flight it starts at its station at 0; a re-plan (it strayed from its
    plan, or one above it did: re-forecast them with :func:`timed.forecast_from`) starts at
    ``from_xy`` at ``t0_s``."""
    fastest = max((mission.vehicle(o.vehicle).speed_m_s for o in others), default=0.0)
    problem = problem_for(mission, grid, shadows, name, others, fastest, memo, from_xy=from_xy, t0_s=t0_s)
    partners = problem.sight_others
    margin = near_margin_m(mission, name, max(mission.vehicle(o.vehicle).speed_m_s for o in partners)) \
        if partners else 0.0
    ladder = [(Blocking.WHOLE_FLIGHT, 0.0), (Blocking.CLOSEST_APPROACH, margin),
              (Blocking.CLOSEST_APPROACH, 0.0), (Blocking.NONE, 0.0)] if partners else [(Blocking.NONE, 0.0)]
    v = mission.vehicle(name)
    start = v.start_enu_m if from_xy is None else from_xy
    for level, margin_m in ladder:
        sol = solve(problem, level, margin_m)
        if sol is not None:
            return to_timed(name, grid, sol, start, v.goal_enu_m), level, problem.model.step_s
    return None


def near_margin_m(mission: "Mission", name: str, fastest_other_m_s: float) -> float:
    """How much the distance between two vehicles may change within one step of ``name``'s
    plan: both at full speed."""
    v = mission.vehicle(name)
    model = step_model(mission.planner.grid_resolution_m, v.speed_m_s, mission.coordination.step_s,
                       mission.safety.min_separation_m, fastest_other_m_s)
    return (v.speed_m_s + fastest_other_m_s) * model.step_s
