"""Frozen copy of companion/planning/astar.py at b4afd9b: the oracle the faster search must match path for path.

Test-only; never imported by the companion. Do not edit.

A* on the 8-connected occupancy grid (paper section III.A), with jump-point pruning.

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

Straight jumps are O(1): numpy precomputes, for every cell and each of the four directions, the
next cell where a straight scan stops, and h for every cell. The search reads these through
memoryviews (no per-cell Python objects are built), keeps g, parent, entry direction and the
closed flags in preallocated flat lists / bytearrays, and pushes (f, h, index) tuples on heapq.
The path between consecutive jump points is a straight or diagonal run of cells and is filled
back in, so the result is the full cell path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from heapq import heappop, heappush
from typing import Literal

import numpy as np

from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import OccupancyGrid

Heuristic = Literal["octile", "euclidean"]

_SQRT2 = math.sqrt(2.0)
_CANCEL_EVERY = 64  # expansions between two polls of the cancel callback

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
    corners = _jump_point_search(free, s_idx, g_idx, heuristic, max_expansions, cancel)
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


def _shifted(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """out[y, x] = a[y + dy, x + dx], False beyond the edge."""
    rows, cols = a.shape
    out = np.zeros_like(a)
    out[max(0, -dy):rows - max(0, dy), max(0, -dx):cols - max(0, dx)] = \
        a[max(0, dy):rows - max(0, -dy), max(0, dx):cols - max(0, -dx)]
    return out


def _stop_tables(free: np.ndarray, goal: int) -> list[memoryview]:
    """For E, W, N, S: the flat index of the next cell where a straight scan stops.

    A scan stops at a blocked cell, at a cell with a forced neighbour, or at the goal. Scans never
    start on the padding, so the sentinel past the end (-1 or rows*cols) is never followed.
    """
    rows, cols = free.shape
    idx = np.arange(rows * cols, dtype=np.int32).reshape(rows, cols)
    up, down, right, left = (_shifted(free, 1, 0), _shifted(free, -1, 0),
                             _shifted(free, 0, 1), _shifted(free, 0, -1))
    forced = {
        _E: (up & ~_shifted(free, 1, -1)) | (down & ~_shifted(free, -1, -1)),
        _W: (up & ~_shifted(free, 1, 1)) | (down & ~_shifted(free, -1, 1)),
        _N: (right & ~_shifted(free, -1, 1)) | (left & ~_shifted(free, -1, -1)),
        _S: (right & ~_shifted(free, 1, 1)) | (left & ~_shifted(free, 1, -1)),
    }
    gy, gx = divmod(goal, cols)
    tables = []
    for d in (_E, _W, _N, _S):
        stop = ~free | (free & forced[d])
        stop[gy, gx] = True
        axis = 1 if d in (_E, _W) else 0
        forward = d in (_E, _N)
        cand = np.where(stop, idx, rows * cols if forward else -1).astype(np.int32)
        nxt = np.full_like(cand, rows * cols if forward else -1)
        if forward:  # suffix minimum, shifted by one: the first stop strictly ahead
            acc = np.flip(np.minimum.accumulate(np.flip(cand, axis), axis=axis), axis)
            if axis == 1:
                nxt[:, :-1] = acc[:, 1:]
            else:
                nxt[:-1, :] = acc[1:, :]
        else:  # prefix maximum, shifted by one
            acc = np.maximum.accumulate(cand, axis=axis)
            if axis == 1:
                nxt[:, 1:] = acc[:, :-1]
            else:
                nxt[1:, :] = acc[:-1, :]
        tables.append(memoryview(np.ascontiguousarray(nxt).ravel()))
    return tables


def _jump_point_search(free_grid: np.ndarray, start: int, goal: int, heuristic: Heuristic,
                       max_expansions: int | None, cancel: Callable[[], bool] | None) -> list[int] | None:
    """Jump points from start to goal (flat padded indices), or None when the goal is walled in."""
    rows, width = free_grid.shape
    n = rows * width
    # One extra False at the end: index -1 (a backward scan's sentinel) then reads "blocked".
    free = memoryview(np.append(free_grid.ravel(), False).view(np.uint8))
    nxt = _stop_tables(free_grid, goal)
    h = memoryview(_heuristic_table(rows, width, goal, heuristic).ravel())
    step = (1, -1, width, -width, width + 1, width - 1, 1 - width, -1 - width)
    unit = (1.0, 1.0, 1.0, 1.0, _SQRT2, _SQRT2, _SQRT2, _SQRT2)
    behind_side = tuple(tuple(-step[d] + step[side] for side in _SIDES[d]) for d in (_E, _W, _N, _S))

    def diagonal_jump(i: int, d: int) -> int:
        a, b = _PARTS[d]
        s, sa, sb, ta, tb = step[d], step[a], step[b], nxt[a], nxt[b]
        while free[i + sa] and free[i + sb] and free[i + s]:
            i += s
            if i == goal or free[ta[i]] or free[tb[i]]:
                return i
        return -1

    g = [math.inf] * n
    parent = [-1] * n
    came = bytearray(n)  # direction code + 1 of the move into each jump point; 0 = the start
    closed = bytearray(n)
    g[start] = 0.0
    heap = [(h[start], h[start], start)]
    expansions = 0
    while heap:
        _, _, i = heappop(heap)
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
        if max_expansions is not None and expansions > max_expansions:
            raise BudgetExceeded(f"expansion budget of {max_expansions} jump points spent before reaching the goal")
        if cancel is not None and expansions % _CANCEL_EVERY == 1 and cancel():
            raise BudgetExceeded(f"search cancelled after {expansions} expansions")
        d = came[i] - 1
        if d < 0:
            moves = _ALL_MOVES
        elif d < 4:
            left, right = behind_side[d]
            moves = _STRAIGHT_MOVES[d][(not free[i + left]) | (not free[i + right]) << 1]
        else:
            moves = _DIAGONAL_MOVES[d]
        gi = g[i]
        for m in moves:
            if m < 4:
                j = nxt[m][i]
                if not free[j]:
                    continue
            else:
                j = diagonal_jump(i, m)
                if j < 0:
                    continue
            ng = gi + (j - i) // step[m] * unit[m]
            if ng < g[j]:
                g[j] = ng
                parent[j] = i
                came[j] = m + 1
                hj = h[j]
                heappush(heap, (ng + hj, hj, j))
    return None


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
