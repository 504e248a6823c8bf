"""Space-time reachability for one lower-priority vehicle, as a numpy wavefront over the grid.

The vehicle lives on the mission grid's free cells (the inflated static obstacles, so static
clearance holds), one time step of ``step_s`` at a time. In a step it makes a few sub-steps
through free cells, alternating 4- and 8-neighbour moves (an octagon that never exceeds its
cruise speed; see :func:`step_model`), or stays: waits and slow moves are the same sub-steps cut
short. At each step instant k it must be ``allowed``: far enough from every higher-priority
vehicle (at its forecast position) and, depending on the :class:`SightRule`, out of its sight.

Reachability is a set per step, so each step is a few shifted ORs of a boolean array:

    F[k+1] = grow(F[k]) & allowed(k+1)          forward, from the start cell at k = 0
    B[k]   = grow(B[k+1]) & allowed(k)          backward, from the goal cell at the horizon

F[k] & B[k] are the states on some start-to-goal path, found back from the goal within the forward
sets, without ``allowed`` (:func:`on_path`). Once every higher-priority vehicle has arrived,
``allowed`` no longer changes; each pass stops there as soon as its set stops changing (the sets
are the same for every later step). ``allowed(k)`` is read only among the cells grown from step
k - 1, so its sight-shadow masks are computed on those cells' tiles only (:class:`AllowedTable`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from companion.planning.coordination import bitgrid, tiles
from companion.planning.budget import Budget, spend
from companion.planning.grid import OccupancyGrid
from companion.planning.coordination.shadow import ShadowMask, SightShadows
from companion.planning.timed_route import TimedRoute


class SightRule(Enum):
    """What a step instant requires of the sight line to each higher-priority vehicle."""

    BLOCKED = "blocked"          # always blocked (the whole flight)
    BLOCKED_WHEN_NEAR = "near"   # blocked whenever the squared distance is <= a threshold D^2
    FREE = "free"                # no requirement (separation only)


@dataclass(frozen=True)
class StepModel:
    """How a vehicle moves on the space-time graph."""

    step_s: float
    moves: tuple[int, ...]  # the sub-steps of one step: 4- or 8-neighbour, a palindrome
    min_distance_m: float   # to each higher-priority vehicle at step instants (covers the step)


def step_model(resolution_m: float, speed_m_s: float, nominal_step_s: float, min_separation_m: float,
               fastest_other_m_s: float) -> StepModel:
    """n sub-steps (n = cells flown at cruise in ``nominal_step_s``), of which k = floor(0.414 n)
    may be diagonal. Their octagon reaches at most sqrt(n^2 + k^2) cells, so the step lasts
    that many cells' flight time: no direction is faster than cruise, none much slower (n = 5:
    within 8 %). Separation is required at step instants with the margin that keeps it between
    them: two vehicles moving linearly, ``sep`` apart at both ends of a step of relative length
    L, are at least sqrt(d^2 - (L/2)^2) apart in between."""
    n = max(1, round(nominal_step_s * speed_m_s / resolution_m))
    k = math.floor((math.sqrt(2.0) - 1.0) * n)
    eights = {round((j + 0.5) * n / k - 0.5) for j in range(k)} if k else set()
    moves = [8 if i in eights else 4 for i in range(n)]
    moves = moves[:(n + 1) // 2] + moves[:n // 2][::-1]  # a palindrome, so paths reverse
    step_s = math.hypot(n, moves.count(8)) * resolution_m / speed_m_s
    rel_m = (speed_m_s + fastest_other_m_s) * step_s
    return StepModel(step_s, tuple(moves), math.hypot(min_separation_m, rel_m / 2.0))


class SpaceTimeProblem:
    """One lower-priority vehicle against the forecasts of the vehicles above it. Masks are
    packed (:mod:`bitgrid`); ``memo`` may be shared by problems on the same grid and model.
    ``sight``: the names among ``others`` whose sight line the rules keep blocked (None: all of
    them); separation is kept from every one."""

    def __init__(self, grid: OccupancyGrid, shadows: SightShadows, model: StepModel,
                 start_xy: tuple[float, float], goal_xy: tuple[float, float],
                 others: tuple[TimedRoute, ...], horizon_s: float, memo: dict | None = None, t0_s: float = 0.0,
                 budget: Budget | None = None, sight: tuple[str, ...] | None = None):
        self.grid = grid
        self.budget = budget  # charged a unit per allowed mask and per grown set, and each shadow mask's cost
        self.shadows = shadows
        self.model = model
        self.start = _cell(grid, start_xy)
        self.goal = _cell(grid, goal_xy)
        free = ~grid.occupied
        free[self.start[1], self.start[0]] = True  # a station's cell may touch the inflation
        free[self.goal[1], self.goal[0]] = True
        self.free = free
        self.free_bits = bitgrid.pack(free)
        self.nx = free.shape[1]
        self.others = others
        self._sight = None if sight is None else tuple(i for i, o in enumerate(others) if o.vehicle in sight)
        self.sight_others = others if self._sight is None else tuple(others[i] for i in self._sight)
        self.t0_s = t0_s  # step 0 is this mission time (a re-plan starts mid-flight)
        self.horizon = max(1, int((horizon_s - t0_s) // model.step_s))
        settled_s = max((o.arrival_s for o in others), default=t0_s)
        self.settled = min(self.horizon, max(0, math.ceil((settled_s - t0_s) / model.step_s)))  # allowed is fixed from here
        xs, ys = grid.cell_centres()
        self._xs, self._ys = xs, ys
        self._memo = {} if memo is None else memo
        self._blocked: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # blocked_by_all's, with its tiles
        self._stacks: dict[tuple, np.ndarray] = {}
        self._shadow_stacks: dict[int, list] = {}  # per step: [masks, stacked, tiles covered]
        self.all_tiles = shadows.all_tiles
        self._no_points = np.zeros((0, 2))
        self.tables: dict[tuple, "AllowedTable"] = {}  # allowed_table's, by (rule, near2)
        self._none = np.zeros((0,) + self.free_bits.shape, dtype=np.uint64)
        self._positions = self._positions_upto(self.settled)

    def _positions_upto(self, last: int) -> list[list[tuple[float, float]]]:
        """Every higher vehicle's forecast position (rounded to the micrometre: memo keys) at
        steps 0..last, as a list per step (each forecast read once, at all the steps' times)."""
        t = self.t0_s + np.arange(last + 1) * self.model.step_s
        per_other = [[(round(x, 6), round(y, 6)) for x, y in o.planned_position_at(t).tolist()] for o in self.others]
        return [list(at_k) for at_k in zip(*per_other)] if per_other else [[] for _ in range(last + 1)]

    def positions(self, k: int) -> list[tuple[float, float]]:
        return self._positions[min(k, self.settled)]

    def sight_positions(self, k: int) -> list[tuple[float, float]]:
        """The positions at step k of the vehicles whose sight line is kept blocked (``sight``)."""
        at = self.positions(k)
        return at if self._sight is None else [at[i] for i in self._sight]

    def _memoised(self, key: tuple, make) -> np.ndarray:
        value = self._memo.get(key)
        if value is None:
            value = self._memo[key] = make()
        return value

    def shadow_mask(self, xy: tuple[float, float]) -> ShadowMask:
        return self._memoised(("shadow", xy), lambda: ShadowMask(self.shadows, xy, self.budget))

    def far_bits(self, xy: tuple[float, float]) -> np.ndarray:
        return self._memoised(("far", xy, self.model.min_distance_m), lambda: bitgrid.farther(
            self._xs, self._ys, xy, self.model.min_distance_m ** 2, strict=False))

    def allowed(self, k: int, rule: SightRule, near2_m2: float = math.inf, need: np.ndarray | None = None) -> np.ndarray:
        """Packed cells allowed at step k, exact on the tiles of tile map ``need`` (:mod:`tiles`;
        default: every tile); ``near2_m2``: the squared D of BLOCKED_WHEN_NEAR (squared, so that a
        tie with the distance it came from stays a tie)."""
        spend(self.budget)
        return self.allowed_on(k, rule, near2_m2, self.all_tiles if need is None else need)

    def allowed_on(self, k: int, rule: SightRule, near2_m2: float, need: np.ndarray) -> np.ndarray:
        """:meth:`allowed` without charging the budget (a mask already charged, asked on more tiles)."""
        k = min(k, self.settled)
        far = self._stacked(("far", k), lambda: [self.far_bits(xy) for xy in self.positions(k)])
        if rule is SightRule.FREE:
            shadows, points = self._none, self._no_points
        else:
            shadows = self._shadows_on(k, need)
            points = self._stacked(("points", k), lambda: self.sight_positions(k))
        return bitgrid.allowed(self.free_bits, self._xs, self._ys, far, shadows, points,
                               near2_m2 if rule is SightRule.BLOCKED_WHEN_NEAR else None, need)

    def _shadows_on(self, k: int, need: np.ndarray) -> np.ndarray:
        """The shadow masks of step k's ``sight`` positions stacked (m, ny, words), exact on the
        tiles of ``need``: created once per step, stacked again only when asked on more tiles."""
        entry = self._shadow_stacks.get(k)
        if entry is None:
            masks = [self.shadow_mask(xy) for xy in self.sight_positions(k)]
            entry = self._shadow_stacks[k] = [masks, None, None]
        masks, stacked, done = entry
        if len(masks) <= 1:  # a view of the one mask: it stays current as the mask grows
            if stacked is None:
                entry[1] = stacked = masks[0].bits[None] if masks else self._none
            if masks:
                masks[0].cover(need)
        elif stacked is None or tiles.missing(need, done):
            done = entry[2] = need if done is None else done | need
            entry[1] = stacked = np.stack([m.cover(done) for m in masks])
        return stacked

    def _stacked(self, key: tuple, items) -> np.ndarray:
        """The masks (or points) ``items()`` lists for a step, stacked once per problem: every
        table of the problem reads the same ones at that step."""
        value = self._stacks.get(key)
        if value is None:
            got = items()
            if key[0] == "points":
                value = np.array(got, dtype=float).reshape(-1, 2)
            else:
                value = got[0][None] if len(got) == 1 else np.stack(got) if got else self._none  # one: a view
            self._stacks[key] = value
        return value

    def goal_allowed(self, k: int, rule: SightRule, near2_m2: float = math.inf) -> bool:
        """Whether the goal cell is in :meth:`allowed` (k, rule, near2_m2): the same sums and
        shadow bits for that one cell."""
        gx, gy = self.goal
        x0, y0 = float(self._xs[gx]), float(self._ys[gy])
        d2 = [(x0 - x) * (x0 - x) + (y0 - y) * (y0 - y) for x, y in self.positions(k)]
        if min(d2, default=math.inf) < self.model.min_distance_m ** 2:
            return False
        if rule is SightRule.FREE:
            return True
        sight = range(len(d2)) if self._sight is None else self._sight
        return all(self.shadow_mask(self.positions(k)[i]).test(gx, gy)
                   or (rule is SightRule.BLOCKED_WHEN_NEAR and d2[i] > near2_m2) for i in sight)

    def blocked_by_all(self, k: int, bits: np.ndarray | None = None) -> np.ndarray:
        """Packed free cells blocked from every vehicle of ``sight`` at step k, among packed
        ``bits`` (default: every cell). Kept per step: the first ask on its tiles only, an ask
        beyond them on the whole grid (as :meth:`AllowedTable.at`)."""
        k = min(k, self.settled)
        entry = self._blocked.get(k)
        if entry is None or entry[1] is not None and (bits is None or tiles.spills(bits, entry[1])):
            done = tiles.tiles_of(bits) if entry is None and bits is not None else None
            out = self.free_bits.copy()
            for xy in self.sight_positions(k):
                out &= self.shadow_mask(xy).cover(self.all_tiles if done is None else done)
            entry = self._blocked[k] = (out, done)
        return entry[0] if bits is None else bits & entry[0]

    def nearest_d2(self, k: int, bits: np.ndarray) -> tuple[float, tuple[int, int]]:
        """The least squared distance to a vehicle of ``sight`` over the cells of ``bits`` at step k."""
        return bitgrid.nearest(bits, self._xs, self._ys, self.sight_positions(k))

    def grow(self, bits: np.ndarray) -> np.ndarray:
        """Cells reachable from packed ``bits`` in one step (sub-steps ``model.moves``)."""
        spend(self.budget)
        return bitgrid.grow(bits, self.free_bits, self.model.moves)

    def cell_mask(self, cell: tuple[int, int]) -> np.ndarray:
        return bitgrid.single(self.free_bits.shape, cell[0], cell[1])

    def has(self, bits: np.ndarray, cell: tuple[int, int]) -> bool:
        return bitgrid.test(bits, cell[0], cell[1])


def _cell(grid: OccupancyGrid, xy: tuple[float, float]) -> tuple[int, int]:
    ny, nx = grid.shape
    ix, iy = grid.world_to_cell(float(xy[0]), float(xy[1]))
    return min(max(ix, 0), nx - 1), min(max(iy, 0), ny - 1)


class Layers:
    """Reachable sets per step k = first..horizon: ``head`` from ``first`` on, ``tail`` (latest
    first) ending at the horizon, and between them the last of ``head`` (a set that stopped
    changing once ``allowed`` did)."""

    def __init__(self, first: int, head: list[np.ndarray], horizon: int, tail: list[np.ndarray] | None = None):
        self.first = first
        self.head = head
        self.horizon = horizon
        self.tail = tail or []

    def __getitem__(self, k: int) -> np.ndarray:
        if k - self.first < len(self.head):
            return self.head[k - self.first]
        if k > self.horizon - len(self.tail):
            return self.tail[self.horizon - k]
        return self.head[-1]

    @property
    def empty(self) -> bool:
        return not self.head[-1].any()


def forward(problem: SpaceTimeProblem, allowed: "AllowedTable", seed: np.ndarray, k0: int,
            stop_at_arrival: bool = False) -> Layers:
    """F[k] for k = k0..horizon from ``seed`` (already allowed at k0). With ``stop_at_arrival``
    it stops at the earliest arrival (the goal reached, and allowed from then on)."""
    masks = [seed]
    stay: int | None = None
    for k in range(k0 + 1, problem.horizon + 1):
        nxt = allowed.after(masks[-1], k)
        if k > problem.settled and np.array_equal(nxt, masks[-1]):
            break
        masks.append(nxt)
        if not nxt.any():
            break
        if stop_at_arrival and problem.has(nxt, problem.goal):
            stay = stay_from(problem, allowed) if stay is None else stay
            if stay is not None and k >= stay:
                break
    return Layers(k0, masks, problem.horizon)


def on_path(problem: SpaceTimeProblem, fwd: Layers) -> Layers:
    """P[k] = F[k] & B[k] for k = 0..horizon: the states of forward layers ``fwd`` (from step 0)
    from which the goal is reached by the horizon. A successor of a state of F[k] that is allowed
    at k + 1 is in F[k + 1], so P[k] = grow(P[k + 1]) & F[k] from the goal cell in F[horizon]:
    B (the backward pass on the allowed masks) without its masks, on the forward sets only."""
    steady = fwd.first + len(fwd.head) - 1  # F is fixed from here on
    tail = [problem.cell_mask(problem.goal) & fwd[problem.horizon]]
    k = problem.horizon  # tail[-1] is P[k]
    while k > steady:  # grow until the set stops changing
        nxt = problem.grow(tail[-1]) & fwd[k - 1]
        if np.array_equal(nxt, tail[-1]):
            break
        tail.append(nxt)
        k -= 1
    head = [tail.pop()]
    for j in range(min(k, steady) - 1, -1, -1):
        head.append(problem.grow(head[-1]) & fwd[j])
    head.reverse()  # head[j] = P[j], its last entry the steady set
    return Layers(0, head, problem.horizon, tail)


class AllowedTable:
    """allowed(k) under one rule, computed on first use (a dead forward pass never asks for
    the later steps) and on the tiles asked for (the sets a search reaches); from ``settled`` on
    every step is the same."""

    def __init__(self, problem: SpaceTimeProblem, rule: SightRule, near2_m2: float = math.inf):
        self.problem, self.rule, self.near2_m2 = problem, rule, near2_m2
        self._masks: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # per step: the mask, its tiles

    def at(self, k: int, bits: np.ndarray) -> np.ndarray:
        """The cells of packed ``bits`` allowed at step k. The first ask at a step computes the
        mask on its tiles only; an ask beyond them (another pass) on the whole grid."""
        p = self.problem
        k = min(k, p.settled)
        entry = self._masks.get(k)
        if entry is None:
            need = tiles.tiles_of(bits) if self.rule is not SightRule.FREE else None
            entry = self._masks[k] = (p.allowed(k, self.rule, self.near2_m2, need), need)
        elif entry[1] is not None and tiles.spills(bits, entry[1]):
            entry = self._masks[k] = (p.allowed_on(k, self.rule, self.near2_m2, p.all_tiles), None)
        return bits & entry[0]

    def after(self, bits: np.ndarray, k: int) -> np.ndarray:
        """The cells reached from packed ``bits`` in one step and allowed at step k."""
        return self.at(k, self.problem.grow(bits))

    def __len__(self) -> int:
        return self.problem.settled + 1


def allowed_table(problem: SpaceTimeProblem, rule: SightRule, near2_m2: float = math.inf) -> AllowedTable:
    """The problem's table for ``rule`` at ``near2_m2``, one per pair (the closest-approach
    witness's last round and the first distance of its ladder ask for the same one)."""
    key = (rule, near2_m2)
    table = problem.tables.get(key)
    if table is None:
        table = problem.tables[key] = AllowedTable(problem, rule, near2_m2)
    return table


def stay_from(problem: SpaceTimeProblem, table: AllowedTable) -> int | None:
    """The first step from which the goal cell stays allowed to the horizon (None: never): the
    goal cell alone tested (:meth:`SpaceTimeProblem.goal_allowed`), from the last step back to
    the last it is not allowed, no whole mask built."""
    last = len(table) - 1
    if not problem.goal_allowed(last, table.rule, table.near2_m2):
        return None
    return next((k + 1 for k in range(last - 1, -1, -1) if not problem.goal_allowed(k, table.rule, table.near2_m2)), 0)


def earliest_arrival(problem: SpaceTimeProblem, layers: Layers, not_before: int) -> int | None:
    """The first step k >= ``not_before`` at which the goal cell is in ``layers``."""
    last = layers.first + len(layers.head) - 1
    for k in range(max(not_before, layers.first), min(last, problem.horizon) + 1):
        if problem.has(layers[k], problem.goal):
            return k
    if problem.has(layers.head[-1], problem.goal) and max(not_before, last) <= problem.horizon:
        return max(not_before, last)
    return None
