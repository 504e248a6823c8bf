"""A* on the 8-connected occupancy grid (paper section III.A), with jump-point pruning.

Moves cost 1 (straight) or sqrt(2) (diagonal) cells. A diagonal move needs both cells it squeezes
between to be free (no corner cutting). The octile and Euclidean heuristics are consistent for
these costs, so the first pop of the goal is optimal and nothing is ever reopened.

On a uniform-cost grid a plain A* spends its time on the many equal-cost orderings of the same
moves: in the reference map it expands ~39 000 cells (170 ms in CPython). Jump Point Search
(Harabor & Grastien 2011; the no-corner-cutting rules of their 2014 paper) keeps one canonical
ordering, "diagonal first", and pushes only the cells where that ordering must turn: 46 in the
reference map. The path cost is the same optimum; tests check it against a brute Dijkstra.

Pruning, for a cell x reached from its parent p:
  * moving straight (say east): continue east; if the cell north of p is blocked, north and
    north-east of x are forced (p cannot reach them diagonally); the same for south.
  * moving diagonally (say north-east): continue north, east and north-east; with no corner
    cutting a diagonal move never forces anything.
  * a straight jump stops at the goal, at a cell with a forced neighbour (a jump point), or
    fails at a blocked cell; a diagonal jump stops where either straight jump would succeed.

Jumps cost O(1) Python work per jump point: numpy precomputes, for every cell, how far each
straight scan runs and whether it lands (one running minimum / maximum per direction), the state of
one diagonal step (blocked / lands / steps on), which cells behind it are blocked, and h. On grids
of scattered blocked cells nearly every cell is a jump point (~160 000 expansions at 1000 x 1000,
20 % blocked), so the per-expansion Python work is what counts: the search reads the tables through
memoryviews (no per-cell Python objects are built), keeps g, parent, entry direction and the closed
flags in preallocated flat lists / bytearrays, and pushes (f, h, index) tuples on heapq, merging
each expansion's last push into the next pop (heappushpop: the same pop order, one sift less).
With numba installed (the ``fast`` extra) :mod:`.astar_jit` runs the same search compiled, about
ten times faster, and returns the same jump points.
The path between consecutive jump points is a straight or diagonal run of cells and is filled
back in, so the result is the full cell path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from heapq import heappop, heappush, heappushpop
from typing import Literal

import numpy as np

from companion.planning import astar_jit
from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import OccupancyGrid

Heuristic = Literal["octile", "euclidean"]

_SQRT2 = math.sqrt(2.0)
_CANCEL_EVERY = astar_jit.POLL_EVERY  # expansions between two polls of the cancel callback

# Directions: the four straight ones index the stop tables; a diagonal is a pair of them. All the
# tables below are tuples indexed by direction code (constants, read in the hot loop).
_E, _W, _N, _S, _NE, _NW, _SE, _SW = range(8)
_PARTS = ((), (), (), (), (_E, _N), (_W, _N), (_E, _S), (_W, _S))  # a diagonal's straight parts
_SIDES = ((_N, _S), (_N, _S), (_E, _W), (_E, _W))                  # a straight move's two sides


def _diagonal(a: int, b: int) -> int:
    return next(d for d in (_NE, _NW, _SE, _SW) if set(_PARTS[d]) == {a, b})


# Moves to try from a jump point, by how it was entered. From the start: all eight. After a
# straight move: straight on, plus each side (and the diagonal to it) whose cell behind is
# blocked, indexed by a 2-bit mask of those sides. After a diagonal move: its two parts and itself.
_ALL_MOVES = tuple(range(8))
_STRAIGHT_MOVES = tuple(
    tuple((d,) + sum(((side, _diagonal(d, side)) for k, side in enumerate(_SIDES[d]) if mask >> k & 1), ())
          for mask in range(4))
    for d in (_E, _W, _N, _S))
_DIAGONAL_MOVES = tuple((*_PARTS[d], d) if _PARTS[d] else () for d in range(8))


def astar(grid: OccupancyGrid, start_xy: tuple[float, float], goal_xy: tuple[float, float], *,
          max_expansions: int | None = None, cancel: Callable[[], bool] | None = None,
          heuristic: Heuristic = "octile") -> np.ndarray:
    """Shortest 8-connected grid path from ``start_xy`` to ``goal_xy`` (ENU metres).

    Returns an (N, 2) array of cell centres, N >= 2, whose first and last rows are the exact start
    and goal points. Raises :class:`NoPath` (start or goal outside the grid or in an occupied
    cell, goal walled in) or :class:`BudgetExceeded` (more than ``max_expansions`` jump points
    expanded, or ``cancel()`` returned True; it is polled at the first expansion and every 64 after).
    """
    if heuristic not in ("octile", "euclidean"):
        raise ValueError(f"heuristic must be 'octile' or 'euclidean', got {heuristic!r}")
    if max_expansions is not None and max_expansions < 1:
        raise ValueError(f"max_expansions must be a positive integer, got {max_expansions!r}")
    s_cell = _endpoint_cell(grid, start_xy, "start")
    g_cell = _endpoint_cell(grid, goal_xy, "goal")
    start = (float(start_xy[0]), float(start_xy[1]))
    goal = (float(goal_xy[0]), float(goal_xy[1]))
    if s_cell == g_cell:
        return np.array([start, goal])

    ny, nx = grid.shape
    width = nx + 2  # one blocked cell of padding on every side: no bounds checks in the search
    free = np.zeros((ny + 2, width), dtype=bool)
    free[1:-1, 1:-1] = ~grid.occupied
    s_idx = (s_cell[1] + 1) * width + s_cell[0] + 1
    g_idx = (g_cell[1] + 1) * width + g_cell[0] + 1
    search = _jump_point_search if astar_jit.search is None else _compiled_jump_point_search
    corners = search(free, s_idx, g_idx, heuristic, max_expansions, cancel)
    if corners is None:
        raise NoPath(f"goal ({goal[0]:.1f}, {goal[1]:.1f}) unreachable from start "
                     f"({start[0]:.1f}, {start[1]:.1f}): walled in")

    iy, ix = np.divmod(_fill_runs(np.asarray(corners, dtype=np.int64), width), width)
    path = np.column_stack([grid.origin_m[0] + (ix - 0.5) * grid.resolution_m,
                            grid.origin_m[1] + (iy - 0.5) * grid.resolution_m])
    path[0] = start
    path[-1] = goal
    return path


def path_length_m(path: np.ndarray) -> float:
    """Length of a polyline (N, 2) in metres."""
    p = np.asarray(path, dtype=float)
    return float(np.sum(np.hypot(*np.diff(p, axis=0).T))) if len(p) > 1 else 0.0


def _endpoint_cell(grid: OccupancyGrid, xy: tuple[float, float], what: str) -> tuple[int, int]:
    x, y = float(xy[0]), float(xy[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise NoPath(f"{what} ({x}, {y}) is not a finite point")
    ix, iy = grid.world_to_cell(x, y)
    if not grid.in_bounds(ix, iy):
        x0, y0, x1, y1 = grid.extent_m
        raise NoPath(f"{what} ({x:.1f}, {y:.1f}) is outside the grid "
                     f"[{x0:.1f}, {x1:.1f}] x [{y0:.1f}, {y1:.1f}]")
    if grid.occupied[iy, ix]:
        raise NoPath(f"{what} ({x:.1f}, {y:.1f}) is inside an inflated obstacle "
                     f"(grid cell ({ix}, {iy}) is occupied)")
    return ix, iy


def _jump_tables(free_grid: np.ndarray, goal: int) -> list[memoryview]:
    """Per direction, what a jump from each cell does (flat padded grid, values for pad cells unused).

    E, W, N, S (int32): the number of cells to the next cell where a straight scan stops if that
    cell is free (a forced neighbour, or the goal), else <= 0 (the scan runs into a blocked cell).
    NE, NW, SE, SW (uint8): the state of one diagonal step: 0 blocked (or squeezing between blocked
    cells), 1 it lands (the goal, or a cell from which a straight part lands), 2 it steps on.
    Every row starts and ends with a blocked pad cell, so runs never wrap into the next row.
    """
    rows, width = free_grid.shape
    n = rows * width
    pad = width + 1
    flat = np.zeros(n + 2 * pad, dtype=bool)  # flat free cells with a blocked margin: shifts are views
    flat[pad:pad + n] = free_grid.ravel()
    blocked_flat = ~flat

    def at(k: int) -> np.ndarray:
        """free[i + k] for every flat i (blocked beyond the grid), a view."""
        return flat[pad + k:pad + k + n]

    def blocked_at(k: int) -> np.ndarray:
        return blocked_flat[pad + k:pad + k + n]

    up, down, right, left = at(width), at(-width), at(1), at(-1)
    stops = (  # blocked, or a forced neighbour
        (up & blocked_at(width - 1)) | (down & blocked_at(-width - 1)),     # E
        (up & blocked_at(width + 1)) | (down & blocked_at(-width + 1)),     # W
        (right & blocked_at(1 - width)) | (left & blocked_at(-1 - width)),  # N
        (right & blocked_at(width + 1)) | (left & blocked_at(width - 1)),   # S
    )
    blocked = blocked_at(0)
    position = np.arange(n, dtype=np.int32)
    row = np.arange(rows, dtype=np.int32)[:, None]
    tables: list[np.ndarray] = []
    for d, stop in enumerate(stops):
        stop |= blocked
        stop[goal] = True
        if d in (_E, _W):  # along the flat array: the pad cells end every row
            tables.append(_runs(stop, blocked, position, 0, d == _E))
        else:  # down the columns
            tables.append(_runs(stop.reshape(rows, width), blocked.reshape(rows, width), row, 0,
                                d == _N).ravel())
    step = (1, -1, width, -width, width + 1, width - 1, 1 - width, -1 - width)
    lands = [t > 0 for t in tables]
    for d in (_NE, _NW, _SE, _SW):
        a, b = _PARTS[d]
        s = step[d]
        moves = at(s) & at(step[a]) & at(step[b])  # the next diagonal step is legal
        here = lands[a] | lands[b]  # a diagonal jump stops on a cell where a straight part lands
        here[goal] = True
        ahead = np.zeros(n, dtype=bool)  # here[i + s], False beyond the grid
        if s > 0:
            ahead[:n - s] = here[s:]
        else:
            ahead[-s:] = here[:n + s]
        state = moves.view(np.uint8) * np.uint8(2)
        state -= moves & ahead
        tables.append(state)
    return [memoryview(t) for t in tables]


def _runs(stop: np.ndarray, blocked: np.ndarray, coord: np.ndarray, axis: int, forward: bool) -> np.ndarray:
    """For every cell: how many cells along ``axis`` to the next stop strictly ahead (``forward``:
    increasing ``coord``) if that stop is free, else a number <= 0 (a blocked stop, or none).

    One running minimum (maximum going backwards) of 2 * coord + blocked over the stops finds the
    next stop and whether it is blocked, with no gather; ``coord`` broadcasts against ``stop``.
    """
    none = np.int32(2**31 - 1 if forward else -1)  # odd, so "no stop" reads as a blocked one
    keys = coord * np.int32(2) + blocked  # 2 * coord + blocked where there is a stop, else none
    keys -= none
    keys *= stop
    keys += none
    scan = np.flip(keys, axis) if forward else keys
    (np.minimum if forward else np.maximum).accumulate(scan, axis=axis, out=scan)
    ahead = [slice(None)] * keys.ndim
    here = list(ahead)
    ahead[axis], here[axis] = (slice(1, None), slice(None, -1)) if forward else (slice(None, -1), slice(1, None))
    found = keys[tuple(ahead)]
    runs = np.full(keys.shape, -1, dtype=np.int32)
    out = runs[tuple(here)]
    np.right_shift(found, 1, out=out)
    if forward:
        out -= coord[tuple(here)]
    else:
        np.subtract(coord[tuple(here)], out, out=out)
    found &= 1  # keys are spent: reuse them for the blocked flag
    found *= np.int32(2**30)
    out -= found  # blocked: far below zero
    return runs


def _jump_point_search(free_grid: np.ndarray, start: int, goal: int, heuristic: Heuristic,
                       max_expansions: int | None, cancel: Callable[[], bool] | None) -> list[int] | None:
    """Jump points from start to goal (flat padded indices), or None when the goal is walled in."""
    rows, width = free_grid.shape
    n = rows * width
    jump = _jump_tables(free_grid, goal)
    h = memoryview(_heuristic_table(rows, width, goal, heuristic).ravel())
    step = (1, -1, width, -width, width + 1, width - 1, 1 - width, -1 - width)
    unit = (1.0, 1.0, 1.0, 1.0, _SQRT2, _SQRT2, _SQRT2, _SQRT2)
    # Each move as (came code, jump table, step, unit), in the order the pruning rules list them,
    # indexed by the came code of the cell they leave from (0: the start).
    move = tuple((m + 1, jump[m], step[m], unit[m]) for m in range(8))
    all_moves = tuple(move[m] for m in _ALL_MOVES)
    straight_moves = (None,) + tuple(tuple(tuple(move[m] for m in ms) for ms in by_mask)
                                     for by_mask in _STRAIGHT_MOVES)
    diagonal_moves = (None,) + tuple(tuple(move[m] for m in ms) for ms in _DIAGONAL_MOVES)
    behind = (None,) + _behind_blocked(free_grid, step)

    g = [math.inf] * n
    parent = [-1] * n
    came = bytearray(n)  # direction code + 1 of the move into each jump point; 0 = the start
    closed = bytearray(n)
    g[start] = 0.0
    heap = [(h[start], h[start], start)]
    budget = n if max_expansions is None else max_expansions  # n: more expansions than cells is impossible
    next_poll = 1 if cancel is not None else n + 1
    expansions = 0
    pending = None  # the last push of an expansion, merged into the next pop (same order, one sift)
    while heap or pending:
        if pending is None:
            i = heappop(heap)[2]
        else:
            i = heappushpop(heap, pending)[2]
            pending = None
        if closed[i]:
            continue
        if i == goal:
            corners = [i]
            while i != start:
                i = parent[i]
                corners.append(i)
            corners.reverse()
            return corners
        closed[i] = 1
        expansions += 1
        if expansions > budget:
            raise _budget_spent(max_expansions)
        if expansions == next_poll:
            next_poll += _CANCEL_EVERY
            if cancel():  # type: ignore[misc]
                raise _cancelled(expansions)
        c = came[i]
        if c > 4:
            moves = diagonal_moves[c]
        elif c:
            moves = straight_moves[c][behind[c][i]]
        else:
            moves = all_moves
        gi = g[i]
        for code, table, s, u in moves:
            if code < 5:
                run = table[i]
                if run <= 0:
                    continue
                j = i + run * s
            else:  # walk the diagonal on its step states; short on cluttered grids
                j = i
                t = table[j]
                while t == 2:
                    j += s
                    t = table[j]
                if not t:
                    continue
                j += s
                run = (j - i) // s
            ng = gi + run * u
            if ng < g[j]:
                g[j] = ng
                parent[j] = i
                came[j] = code
                hj = h[j]
                if pending is not None:
                    heappush(heap, pending)
                pending = (ng + hj, hj, j)
    return None


def _compiled_jump_point_search(free_grid: np.ndarray, start: int, goal: int, heuristic: Heuristic,
                                max_expansions: int | None,
                                cancel: Callable[[], bool] | None) -> list[int] | None:
    """:func:`_jump_point_search` run by the compiled search: the same jump points, errors and polls."""
    budget = free_grid.size if max_expansions is None else max_expansions
    status, corners, expansions = astar_jit.jump_points(free_grid, start, goal, heuristic == "octile", budget,
                                                        cancel)
    if status == astar_jit.BUDGET:
        raise _budget_spent(max_expansions)
    if status == astar_jit.CANCELLED:
        raise _cancelled(expansions)
    return corners


def _budget_spent(max_expansions: int | None) -> BudgetExceeded:
    return BudgetExceeded(f"expansion budget of {max_expansions} jump points spent before reaching the goal")


def _cancelled(expansions: int) -> BudgetExceeded:
    return BudgetExceeded(f"search cancelled after {expansions} expansions")


def _behind_blocked(free_grid: np.ndarray, step: tuple[int, ...]) -> tuple[memoryview, ...]:
    """For E, W, N, S: which sides behind each cell are blocked (bit 0: first side, bit 1: second).

    After a straight move these pick the forced moves (``_STRAIGHT_MOVES``).
    """
    n = free_grid.size
    margin = free_grid.shape[1] + 1
    blocked = np.ones(n + 2 * margin, dtype=np.uint8)  # blocked beyond the grid
    blocked[margin:margin + n] = ~free_grid.ravel()
    out = []
    for d in (_E, _W, _N, _S):
        first, second = (blocked[margin + step[side] - step[d]:][:n] for side in _SIDES[d])
        bits = second * np.uint8(2)
        bits += first
        out.append(memoryview(bits))
    return tuple(out)


def _heuristic_table(rows: int, width: int, goal: int, heuristic: Heuristic) -> np.ndarray:
    """h in cells from every cell of the padded grid to the goal (float64, rows x width)."""
    gy, gx = divmod(goal, width)
    dx = np.abs(np.arange(width, dtype=float) - gx)[None, :]
    dy = np.abs(np.arange(rows, dtype=float) - gy)[:, None]
    if heuristic == "octile":
        return dx + dy + (_SQRT2 - 2.0) * np.minimum(dx, dy)
    return np.hypot(dx, dy)


def _fill_runs(corners: np.ndarray, width: int) -> np.ndarray:
    """Every cell along the straight or diagonal runs between consecutive jump points."""
    cy, cx = np.divmod(corners, width)
    dy, dx = np.diff(cy), np.diff(cx)
    runs = np.maximum(np.abs(dx), np.abs(dy))
    unit = np.sign(dy) * width + np.sign(dx)
    k = np.arange(int(runs.sum())) - np.repeat(np.cumsum(runs) - runs, runs)
    cells = np.repeat(corners[:-1], runs) + k * np.repeat(unit, runs)
    return np.append(cells, corners[-1])
