"""The jump point search of :mod:`companion.planning.astar` compiled (numba), when numba is installed
(the ``fast`` extra); ``search`` is None otherwise and the Python search runs.

It makes the same moves in the same order and pops the same (f, h, index) keys (a total order, so
any binary heap pops them in the order heapq does), so it returns the same jump points, spends the
same expansions and polls ``cancel`` at the same ones: ``tests/planning/test_astar_identity.py``
runs both against the frozen oracle. Instead of the Python search's precomputed tables it scans
each jump as it needs it (the tables' definitions, cell by cell): on a 1000 x 1000 grid building
the tables costs more than a compiled search that touches a few thousand cells.

The grid is the padded ``free`` array of the Python search (one blocked cell around it, flat), so
no scan leaves it. ``cancel`` cannot be called from compiled code: :func:`search` returns
:data:`POLL` at a poll point with its state in the arrays it was given, and resumes from there.
Without numba, ``search`` is None and :func:`jump_points` must not be called.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

try:
    import numba
except ImportError:  # the Python search runs instead
    numba = None

FOUND, EXHAUSTED, BUDGET, POLL, CANCELLED = 0, 1, 2, 3, 4
POLL_EVERY = 64  # expansions between two polls of the cancel callback (both searches)
# counters: heap size, expansions, next poll, the popped cell to expand on resuming (-1: none)
SIZE, EXPANSIONS, NEXT_POLL, RESUME = range(4)


def jump_points(free_grid: np.ndarray, start: int, goal: int, octile: bool, budget: int,
                cancel: Callable[[], bool] | None) -> tuple[int, list[int] | None, int]:
    """(status, the jump points from start to goal when FOUND, expansions) of the search on the
    padded ``free_grid`` (flat indices): FOUND, EXHAUSTED, BUDGET (more than ``budget``
    expansions) or CANCELLED (``cancel()`` said so at the first expansion or one 64 after)."""
    width = free_grid.shape[1]
    n = free_grid.size
    g = np.full(n, math.inf)
    g[start] = 0.0
    parent = np.empty(n, dtype=np.int64)
    came = np.zeros(n, dtype=np.uint8)
    closed = np.zeros(n, dtype=np.uint8)
    heap = np.empty(3 * 1024)  # (f, h, cell) per entry; the search grows it
    counters = np.array([0, 0, 1 if cancel is not None else n + 1, -1], dtype=np.int64)
    free = np.ascontiguousarray(free_grid).ravel().view(np.uint8)
    while True:
        status, heap = search(free, width, start, goal, octile, budget, g, parent, came, closed, heap, counters)
        if status == POLL:
            if cancel():  # type: ignore[misc]
                return CANCELLED, None, int(counters[EXPANSIONS])
            continue
        corners = None
        if status == FOUND:
            corners = [goal]
            i = goal
            while i != start:
                i = int(parent[i])
                corners.append(i)
            corners.reverse()
        return status, corners, int(counters[EXPANSIONS])


search = None
if numba is not None:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _inline = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
    _SQRT2 = math.sqrt(2.0)
    _OCTILE = _SQRT2 - 2.0

    @_inline
    def _h(j, goal, width, octile):
        gy, gx = divmod(goal, width)
        jy, jx = divmod(j, width)
        dx = abs(float(jx) - float(gx))
        dy = abs(float(jy) - float(gy))
        if octile:
            return dx + dy + _OCTILE * min(dx, dy)
        return np.hypot(dx, dy)

    @_inline
    def _forced(free, x, s, t1, t2):
        """A cell reached moving by ``s`` has a forced neighbour on a side (steps t1, t2)."""
        return (free[x + t1] and not free[x + t1 - s]) or (free[x + t2] and not free[x + t2 - s])

    @_inline
    def _straight(free, i, s, t1, t2, goal):
        """Cells from ``i`` to where a straight scan by ``s`` stops if that cell is free, else 0."""
        j = i + s
        while free[j]:
            if j == goal or _forced(free, j, s, t1, t2):
                return (j - i) // s
            j += s
        return 0

    @_inline
    def _diagonal(free, i, s, sa, sb, goal, width):
        """Steps from ``i`` along ``s`` (parts sa, sb) to a cell where either straight part lands
        (or the goal), else 0."""
        j = i
        while free[j + s] and free[j + sa] and free[j + sb]:
            j += s
            if j == goal:
                return (j - i) // s
            if _straight(free, j, sa, _side1(sa, width), -_side1(sa, width), goal) > 0 or \
                    _straight(free, j, sb, _side1(sb, width), -_side1(sb, width), goal) > 0:
                return (j - i) // s
        return 0

    @_inline
    def _side1(s, width):
        """The first side of a straight move (N for E/W, E for N/S), as a step."""
        return width if s == 1 or s == -1 else 1

    @_inline
    def _less(heap, a, b):
        """Entry a's key (f, h, cell) below entry b's; an entry is three floats of ``heap``."""
        a, b = 3 * a, 3 * b
        if heap[a] != heap[b]:
            return heap[a] < heap[b]
        if heap[a + 1] != heap[b + 1]:
            return heap[a + 1] < heap[b + 1]
        return heap[a + 2] < heap[b + 2]

    @_inline
    def _swap(heap, a, b):
        a, b = 3 * a, 3 * b
        for k in range(3):
            heap[a + k], heap[b + k] = heap[b + k], heap[a + k]

    @_inline
    def _push(heap, size, f, h, j):
        """Push (f, h, j) on a heap of ``size`` entries with room for one more."""
        k = size
        heap[3 * k], heap[3 * k + 1], heap[3 * k + 2] = f, h, float(j)
        while k > 0:
            p = (k - 1) >> 1
            if not _less(heap, k, p):
                break
            _swap(heap, k, p)
            k = p

    @_inline
    def _pop(heap, size):
        """Remove the least key from a heap of ``size`` entries; returns its cell."""
        top = int(heap[2])
        size -= 1
        heap[0], heap[1], heap[2] = heap[3 * size], heap[3 * size + 1], heap[3 * size + 2]
        k = 0
        while True:
            c = 2 * k + 1
            if c >= size:
                break
            if c + 1 < size and _less(heap, c + 1, c):
                c += 1
            if not _less(heap, c, k):
                break
            _swap(heap, k, c)
            k = c
        return top

    @_jit
    def search(free, width, start, goal, octile, budget, g, parent, came, closed, heap, counters):  # noqa: F811
        """Run the search until the goal is popped (FOUND), the heap is empty (EXHAUSTED), the
        expansions pass ``budget`` (BUDGET) or reach ``counters[NEXT_POLL]`` (POLL: call again to
        resume). Returns (status, heap): the heap arrays may have grown."""
        steps = np.array((1, -1, width, -width, width + 1, width - 1, 1 - width, -1 - width))
        size = counters[SIZE]
        if size == 0 and counters[EXPANSIONS] == 0:  # the first call: the start alone
            hs = _h(start, goal, width, octile)
            _push(heap, size, hs, hs, start)
            size = 1
        moves = np.empty(8, dtype=np.int64)
        while True:
            i = counters[RESUME]
            if i >= 0:
                counters[RESUME] = -1
            else:
                if size == 0:
                    counters[SIZE] = size
                    return EXHAUSTED, heap
                i = _pop(heap, size)
                size -= 1
                if closed[i]:
                    continue
                if i == goal:
                    counters[SIZE] = size
                    return FOUND, heap
                closed[i] = 1
                counters[EXPANSIONS] += 1
                if counters[EXPANSIONS] > budget:
                    counters[SIZE] = size
                    return BUDGET, heap
                if counters[EXPANSIONS] == counters[NEXT_POLL]:
                    counters[NEXT_POLL] += POLL_EVERY
                    counters[SIZE] = size
                    counters[RESUME] = i
                    return POLL, heap
            c = came[i]
            count = _moves(c, i, free, steps, moves)
            gi = g[i]
            for m in range(count):
                d = moves[m]
                s = steps[d]
                if d < 4:
                    t1 = _side1(s, width)
                    run = _straight(free, i, s, t1, -t1, goal)
                    if run <= 0:
                        continue
                    ng = gi + run * 1.0
                else:
                    sa, sb = _parts(d, width)
                    run = _diagonal(free, i, s, sa, sb, goal, width)
                    if run <= 0:
                        continue
                    ng = gi + run * _SQRT2
                j = i + run * s
                if ng < g[j]:
                    g[j] = ng
                    parent[j] = i
                    came[j] = d + 1
                    hj = _h(j, goal, width, octile)
                    if 3 * (size + 1) > len(heap):
                        heap = np.concatenate((heap, np.empty_like(heap)))
                    _push(heap, size, ng + hj, hj, j)
                    size += 1

    @_inline
    def _parts(d, width):
        """The straight steps of diagonal direction d (NE, NW, SE, SW): (E or W, N or S)."""
        return (1 if d == 4 or d == 6 else -1), (width if d < 6 else -width)

    @_inline
    def _moves(c, i, free, steps, out):
        """The moves to try from a cell entered by direction code ``c`` (0: the start), in the
        Python search's order; returns how many were written to ``out``."""
        if c == 0:
            for d in range(8):
                out[d] = d
            return 8
        d = c - 1
        if d >= 4:  # diagonal: its two straight parts, then itself
            out[0] = 0 if d == 4 or d == 6 else 1
            out[1] = 2 if d < 6 else 3
            out[2] = d
            return 3
        out[0] = d
        count = 1
        s = steps[d]
        # the sides of E/W are N then S; of N/S, E then W: (side, the diagonal between d and it)
        for k in range(2):
            side = (2 + k) if d < 2 else k
            if not free[i + steps[side] - s]:
                out[count] = side
                out[count + 1] = _DIAG[d * 4 + side]
                count += 2
        return count

    # _DIAG[a * 4 + b]: the diagonal made of straight directions a and b (E0 W1 N2 S3)
    _DIAG = np.array([-1, -1, 4, 6,
                      -1, -1, 5, 7,
                      4, 5, -1, -1,
                      6, 7, -1, -1], dtype=np.int64)
