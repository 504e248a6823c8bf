"""Backtracking a space-time path through forward layers (:mod:`spacetime`): from a cell at step k
to one at k - 1 that reaches it in one step, back to the start.

Among the possible predecessors it takes the one deepest inside the reachable set (most slack for
a vehicle that strays from the plan: the most cells of the layer in its 5 x 5 neighbourhood), then
the nearest (a wait rather than a detour), then the first in row order. A step is one compiled
call when numba is installed (integer counts: the same cells as the numpy step).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.coordination import bitgrid

if TYPE_CHECKING:
    from companion.planning.coordination.spacetime import Layers, SpaceTimeProblem

try:
    import numba
except ImportError:  # the numpy step runs instead (the ``fast`` extra brings numba)
    numba = None


def backtrack(problem: "SpaceTimeProblem", layers: "Layers", end: tuple[int, int], k_end: int,
              k_start: int) -> list[tuple[int, int]]:
    """Cells at steps k_start..k_end of a path in ``layers`` that ends at ``end``."""
    moves = np.asarray(problem.model.moves, dtype=np.int64)
    cells = [end]
    for k in range(k_end, k_start, -1):
        cells.append(step_back(layers[k - 1], problem.free, cells[-1], moves))
        if cells[-1][0] < 0:  # cannot happen for a cell of layers[k]: report, don't guess
            raise AssertionError(f"no predecessor of {cells[-2]} at step {k}")
    cells.reverse()
    return cells


def step_back(prev: np.ndarray, free: np.ndarray, cell: tuple[int, int], moves: np.ndarray) -> tuple[int, int]:
    """The predecessor of ``cell`` among the cells of packed layer ``prev`` (see the module doc),
    reaching it through ``free`` (bool) in one step of ``moves``; (-1, -1) when there is none."""
    if _step_back_jit is not None:
        x, y = _step_back_jit(prev, free, cell[0], cell[1], moves)
        return int(x), int(y)
    cx, cy = cell
    r = len(moves)
    ny, nx = free.shape
    x0, x1, y0, y1 = max(cx - r, 0), min(cx + r + 1, nx), max(cy - r, 0), min(cy + r + 1, ny)
    seed = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    seed[cy - y0, cx - x0] = True
    r0 = max(y0 - 2, 0)  # the rows the candidates and their 5 x 5 neighbourhoods span, unpacked
    near = bitgrid.unpack(prev[r0:min(y1 + 2, ny)], nx)
    cand = _grow_bool(seed, free[y0:y1, x0:x1], moves) & near[y0 - r0:y1 - r0, x0:x1]
    ys, xs = np.nonzero(cand)
    if not len(xs):
        return -1, -1
    best = max(zip(xs + x0, ys + y0),
               key=lambda c: (int(near[max(c[1] - 2, 0) - r0:c[1] + 3 - r0, max(c[0] - 2, 0):c[0] + 3].sum()),
                              -((c[0] - cx) ** 2 + (c[1] - cy) ** 2)))
    return int(best[0]), int(best[1])


def _grow_bool(mask: np.ndarray, free: np.ndarray, moves) -> np.ndarray:
    """:func:`bitgrid.grow` on a small unpacked window."""
    m = mask
    for kind in moves:
        row = m.copy()
        row[:, 1:] |= m[:, :-1]
        row[:, :-1] |= m[:, 1:]
        src = row if kind == 8 else m
        out = row.copy()
        out[1:, :] |= src[:-1, :]
        out[:-1, :] |= src[1:, :]
        m = out & free
    return m


_step_back_jit = None
if numba is not None:
    @numba.njit(cache=True, nogil=True)
    def _step_back_jit(prev, free, cx, cy, moves):
        r = len(moves)
        ny, nx = free.shape
        x0, x1, y0, y1 = max(cx - r, 0), min(cx + r + 1, nx), max(cy - r, 0), min(cy + r + 1, ny)
        h, w = y1 - y0, x1 - x0
        m = np.zeros((h, w), dtype=np.bool_)
        m[cy - y0, cx - x0] = True
        row = np.empty_like(m)
        out = np.empty_like(m)
        for kind in moves:
            for iy in range(h):
                for ix in range(w):
                    row[iy, ix] = m[iy, ix] or (ix > 0 and m[iy, ix - 1]) or (ix < w - 1 and m[iy, ix + 1])
            src = row if kind == 8 else m
            for iy in range(h):
                for ix in range(w):
                    v = row[iy, ix] or (iy > 0 and src[iy - 1, ix]) or (iy < h - 1 and src[iy + 1, ix])
                    out[iy, ix] = v and free[y0 + iy, x0 + ix]
            m, out = out, m
        best_n, best_d, bx, by = -1, 0, -1, -1
        for iy in range(h):  # row order, as numpy's nonzero
            for ix in range(w):
                x, y = x0 + ix, y0 + iy
                if not (m[iy, ix] and (prev[y, x >> 6] >> np.uint64(x & 63)) & np.uint64(1)):
                    continue
                n = 0
                for yy in range(max(y - 2, 0), min(y + 3, ny)):
                    for xx in range(max(x - 2, 0), min(x + 3, nx)):
                        if (prev[yy, xx >> 6] >> np.uint64(xx & 63)) & np.uint64(1):
                            n += 1
                d = -((x - cx) ** 2 + (y - cy) ** 2)
                if n > best_n or (n == best_n and d > best_d):
                    best_n, best_d, bx, by = n, d, x, y
        return bx, by
