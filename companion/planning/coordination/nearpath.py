"""The earliest-arriving path whose closest approach is blocked, over a ladder of distances D.

:func:`coordination._near_witness` finds the least D for which some path keeps every open
instant farther than D and has a blocked instant within D (the fixed point D*), and a witness
state at distance D*: the nearest blocked state on any such path. A path forced through that one
state (a cell at one step) may have to wait minutes for it. Any D >= D* gives valid paths too
(the closest approach is within D, so blocked), with more states to pass through (every blocked
state within D) but more instants that must be blocked (every one within D + margin). This
module finds, for one D, the earliest arrival over *all* such paths, with two wavefronts:

    F0[k+1] = grow(F0[k]) & allowed(k+1)                                  reachable
    F1[k+1] = (grow(F1[k]) & allowed(k+1)) | (F0[k+1] & W(k+1))          ... having passed W

W(k) = the states at step k blocked from every higher vehicle it hides from and within D of the
nearest. The
earliest arrival is the first step the goal is in F1 (and stays allowed); the path is
backtracked through F1 until it meets W, then through F0.
"""

from __future__ import annotations

import math

import numpy as np

from companion.planning.coordination import bitgrid
from companion.planning.coordination.backtrack import backtrack
from companion.planning.coordination.spacetime import AllowedTable, Layers, SightRule, SpaceTimeProblem, allowed_table, stay_from


class _Witness:
    """W(k) for one D among given cells (the distance masks kept per step; fixed from
    ``settled`` on, like ``allowed``)."""

    def __init__(self, problem: SpaceTimeProblem, near2_m2: float):
        self.problem, self.near2_m2 = problem, near2_m2
        self._within: dict[int, np.ndarray] = {}

    def at(self, k: int, bits: np.ndarray) -> np.ndarray:
        """The cells of packed ``bits`` in W(k)."""
        p = self.problem
        k = min(k, p.settled)
        within = self._within.get(k)
        if within is None:
            within = self._within[k] = bitgrid.within_any(
                p._xs, p._ys, np.array(p.sight_positions(k), dtype=float).reshape(-1, 2), self.near2_m2)
        return p.blocked_by_all(k, bits & within)


def earliest_near(problem: SpaceTimeProblem, near2_m2: float, margin_m: float,
                  not_after: int | None = None) -> tuple[int, list[tuple[int, int]]] | None:
    """(arrival step, cells from step 0) of the earliest path that has no open instant within
    D + ``margin_m`` of a higher vehicle and a blocked instant within D (``near2_m2`` = D^2,
    squared as in :mod:`coordination`); None when there is none (arriving by ``not_after``)."""
    far2 = (math.sqrt(near2_m2) + margin_m) ** 2 if margin_m else near2_m2
    table = allowed_table(problem, SightRule.BLOCKED_WHEN_NEAR, far2)
    witness = _Witness(problem, near2_m2)
    found = _forward(problem, table, witness, problem.horizon if not_after is None else min(not_after, problem.horizon))
    if found is None:
        return None
    reach, passed, arrive = found
    return arrive, _backtrack(problem, reach, passed, witness, arrive)


def _forward(problem: SpaceTimeProblem, table: AllowedTable, witness: _Witness,
             last: int) -> tuple[Layers, Layers, int] | None:
    start = table.at(0, problem.cell_mask(problem.start))
    stay = stay_from(problem, table)
    if not start.any() or stay is None or stay > last:
        return None
    f0, f1 = [start], [witness.at(0, start)]
    arrive = 0 if stay == 0 and problem.has(f1[0], problem.goal) else None
    k = 0
    while arrive is None and k < last:
        k += 1
        g0 = table.after(f0[-1], k)
        g1 = table.after(f1[-1], k) | witness.at(k, g0)
        if k > problem.settled and np.array_equal(g0, f0[-1]) and np.array_equal(g1, f1[-1]):
            arrive = max(stay, k - 1) if problem.has(g1, problem.goal) else None
            break  # nothing changes any more: the goal is in F1 from now on, or never
        if not g0.any():
            return None
        f0.append(g0)
        f1.append(g1)
        if k >= stay and problem.has(g1, problem.goal):
            arrive = k
    if arrive is None or arrive > last:
        return None
    return Layers(0, f0, problem.horizon), Layers(0, f1, problem.horizon), arrive


def _backtrack(problem: SpaceTimeProblem, reach: Layers, passed: Layers, witness: _Witness,
               arrive: int) -> list[tuple[int, int]]:
    tail = [problem.goal]  # latest first
    k = arrive
    while not problem.has(witness.at(k, reach[k]), tail[-1]):
        tail.append(backtrack(problem, passed, tail[-1], k, k - 1)[0])
        k -= 1
    head = backtrack(problem, reach, tail[-1], k, 0)
    return head + tail[::-1][1:]


def ladder_m2(near2_m2: float, margin_m: float, rungs: int) -> list[float]:
    """The squared distances tried: D*^2, then (D* plus 1, 2, 4 ... margins)^2 (at least 50 m)."""
    unit, near_m = max(margin_m, 50.0), math.sqrt(near2_m2)
    return [near2_m2] + [(near_m + unit * 2 ** i) ** 2 for i in range(rungs - 1)]


def best_near(problem: SpaceTimeProblem, near2_m2: float, margin_m: float,
              rungs: int = 4) -> tuple[float, list[tuple[int, int]]] | None:
    """The earliest-arriving path over the ladder of D from the least feasible D* (``near2_m2``
    = D*^2) on: (its D^2, cells). On a tie the larger D (more of the approach blocked)."""
    best: tuple[int, float, list[tuple[int, int]]] | None = None
    for d2 in ladder_m2(near2_m2, margin_m, rungs):
        found = earliest_near(problem, d2, margin_m, None if best is None else best[0])
        if found is not None and (best is None or found[0] <= best[0]):
            best = (found[0], d2, found[1])
    return None if best is None else (best[1], best[2])
