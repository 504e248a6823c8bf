"""Sight shadows: which grid cells see a point only through a TRUE static obstacle.

``SightShadows(world, grid).blocked_from((x, y))`` is the (ny, nx) mask of cell centres q whose
segment to (x, y) meets a true (un-inflated) static obstacle footprint: the cells where a vehicle
is out of sight of a vehicle at (x, y), in the sense of SPEC §2's ``los_blocked_fraction``.
Vectorised over every cell at once, one obstacle at a time:

  * a circle blocks when the centre's distance to the segment is below the radius (as
    :class:`metrics.TruthGeometry` scores a flight);
  * a convex polygon blocks unless a separating axis exists: one of its edge normals with both
    segment ends outside, or the segment's own line with every vertex strictly on one side;
  * a non-convex polygon is split into triangles (constrained Delaunay), each convex.

Moving obstacles are left out: a plan made before flight must not count on a shadow that moves.

A mask costs :attr:`SightShadows.mask_units` work units of a :mod:`budget`: one per circle and one
per vertex of each convex piece, charged by both paths (the numpy one piece by piece, as it goes;
the compiled one before it starts), so a budget stops at the same mask on either.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from companion.planning.budget import Budget, spend
from companion.planning.coordination import bitgrid, tiles
from companion.planning.grid import OccupancyGrid
from uav_model.world import World

try:
    import numba
except ImportError:  # the numpy masks run instead (the ``fast`` extra brings numba)
    numba = None


def convex_pieces(footprint: shapely.Polygon) -> list[np.ndarray]:
    """The footprint as convex CCW vertex arrays (V, 2): itself when convex, else its triangles."""
    if footprint.convex_hull.area - footprint.area <= 1e-9 * max(footprint.area, 1.0):
        return [_ccw(np.asarray(footprint.exterior.coords, dtype=float)[:-1])]
    tris = shapely.constrained_delaunay_triangles(footprint)
    return [_ccw(np.asarray(t.exterior.coords, dtype=float)[:-1]) for t in tris.geoms]


def _ccw(v: np.ndarray) -> np.ndarray:
    area2 = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
    return v if area2 > 0 else v[::-1].copy()


class SightShadows:
    """The true static obstacles prepared for fast shadow masks over one grid's cell centres."""

    def __init__(self, world: World, grid: OccupancyGrid):
        xs, ys = grid.cell_centres()
        self.shape = grid.shape
        self._qx = xs[None, :]
        self._qy = ys[:, None]
        circles = [o for o in world.static_obstacles if o.is_circle]
        self._circles = [(o.center[0], o.center[1], o.size_m) for o in circles]
        self._inside = [(self._qx - cx) ** 2 + (self._qy - cy) ** 2 < r * r for cx, cy, r in self._circles]
        self._pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (vertices, normals, offsets)
        for o in world.static_obstacles:
            if o.is_circle:
                continue
            for v in convex_pieces(o.footprint):
                edge = np.roll(v, -1, axis=0) - v
                normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1)  # outward for CCW
                self._pieces.append((v, normal, np.einsum("ij,ij->i", normal, v)))
        self._xs, self._ys = xs, ys
        self._circle_rows = np.array(self._circles, dtype=float).reshape(-1, 3)
        if self._pieces:
            self._piece_start = np.cumsum([0] + [len(v) for v, _, _ in self._pieces])
            self._piece_v = np.concatenate([v for v, _, _ in self._pieces])
            self._piece_n = np.concatenate([n for _, n, _ in self._pieces])
            self._piece_off = np.concatenate([o for _, _, o in self._pieces])
        self._bounds = _bounding_discs(self._circle_rows, self._pieces)
        self._extent = max(float(np.abs(xs).max()), float(np.abs(ys).max()), 1.0)
        self.mask_units = len(self._circles) + sum(len(v) for v, _, _ in self._pieces)
        self.all_tiles = tiles.all_tiles(*self.shape)

    def blocked_from(self, xy: tuple[float, float], budget: Budget | None = None) -> np.ndarray:
        """(ny, nx) bool: the segment from each cell centre to ``xy`` meets a true obstacle.
        ``budget``: charged :attr:`mask_units`; :class:`budget.BudgetSpent` when it runs out."""
        px, py = float(xy[0]), float(xy[1])
        if _blocked_jit is not None:
            return bitgrid.unpack(ShadowMask(self, (px, py), budget).cover(self.all_tiles), self.shape[1])
        dx, dy = self._qx - px, self._qy - py  # q - p, broadcast (1, nx) and (ny, 1)
        out = np.zeros(self.shape, dtype=bool)
        len2 = dx * dx + dy * dy
        spend(budget, len(self._circles))
        for (cx, cy, r), inside in zip(self._circles, self._inside):
            # p is outside the disc (a vehicle never is inside); with w = c - p the segment
            # meets the disc when q is inside, or when the foot of c on the line lies within the
            # segment (0 < w.d < |d|^2) at a distance below r (cross^2 < r^2 |d|^2).
            wx, wy = cx - px, cy - py
            along = wx * dx + wy * dy
            cross = dx * wy - dy * wx
            if wx * wx + wy * wy < r * r:  # p inside: everything is blocked
                out[:] = True
                break
            out |= inside | ((along > 0) & (along < len2) & (cross * cross < r * r * len2))
        for v, normal, offset in self._pieces:
            spend(budget, len(v))
            out |= self._meets_convex(px, py, dx, dy, v, normal, offset)
        return out

    def fill(self, bits: np.ndarray, done: np.ndarray, need: np.ndarray, xy: tuple[float, float],
             outside: np.ndarray) -> None:
        """The compiled mask from ``xy`` packed into ``bits`` on the tiles of tile map ``need``
        (:mod:`bitgrid`) that ``done`` has not, and those added to ``done``; ``outside``:
        :meth:`outside`. The same operations per cell as the numpy mask, on the cells each
        obstacle can block (the others cannot be blocked by it), so the same bits."""
        slack = _SLACK * max(self._extent, abs(xy[0]), abs(xy[1]))
        if not self._pieces:
            _blocked_jit(bits, done, need, self._xs, self._ys, xy[0], xy[1], self._circle_rows,
                         np.zeros(1, dtype=np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), outside,
                         self._bounds, slack)
            return
        _blocked_jit(bits, done, need, self._xs, self._ys, xy[0], xy[1], self._circle_rows, self._piece_start,
                     self._piece_v, self._piece_n, self._piece_off, outside, self._bounds, slack)

    def outside(self, xy: tuple[float, float]) -> np.ndarray:
        """Whether ``xy`` is outside each convex piece's edge, in order (a numpy product, as in
        the numpy mask)."""
        if not self._pieces:
            return np.zeros(0, dtype=np.bool_)
        return np.concatenate([normal @ xy - offset > 0 for _, normal, offset in self._pieces])

    def _meets_convex(self, px: float, py: float, dx: np.ndarray, dy: np.ndarray, v: np.ndarray,
                      normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        separated = np.zeros(self.shape, dtype=bool)
        p_side = normal @ (px, py) - offset
        for k in np.flatnonzero(p_side > 0):  # only edges with p outside can separate
            nx, ny = normal[k]
            separated |= nx * self._qx + ny * self._qy > offset[k]
        above = np.ones(self.shape, dtype=bool)
        below = np.ones(self.shape, dtype=bool)
        for vx, vy in v:
            cross = dx * (vy - py) - dy * (vx - px)
            above &= cross > 0
            below &= cross < 0
        return ~(separated | above | below)


class ShadowMask:
    """The sight shadow of one point (:meth:`SightShadows.blocked_from`) packed (:mod:`bitgrid`),
    computed a tile at a time as it is asked for: ``cover(need)`` is exact on the tiles of tile
    map ``need`` and of every earlier ask. A space-time search reads a step's masks only on the
    cells it can reach at that step, often a tenth of the grid. Created, it charges ``budget`` a
    whole mask's units (the numpy path computes the whole mask then, charging as it goes)."""

    __slots__ = ("bits", "done", "_shadows", "_xy", "_outside")

    def __init__(self, shadows: SightShadows, xy: tuple[float, float], budget: Budget | None = None):
        self._shadows, self._xy = shadows, (float(xy[0]), float(xy[1]))
        ny, nx = shadows.shape
        if _blocked_jit is None:
            self.bits = bitgrid.pack(shadows.blocked_from(self._xy, budget))
            self.done, self._outside = shadows.all_tiles, None
            return
        spend(budget, shadows.mask_units)
        self.bits = np.zeros((ny, -(-nx // 64)), dtype=np.uint64)
        self.done = np.zeros(tiles.tile_shape(ny, nx), dtype=np.uint64)
        self._outside = shadows.outside(self._xy)

    def cover(self, need: np.ndarray) -> np.ndarray:
        """The packed mask, exact on the tiles of ``need`` (and of those covered before)."""
        if tiles.missing(need, self.done):
            self._shadows.fill(self.bits, self.done, need, self._xy, self._outside)
        return self.bits

    def test(self, x: int, y: int) -> bool:
        """Whether cell (x, y) is in the shadow (its tile alone computed)."""
        tx, ty = x // _TILE, y // _TILE
        if not bitgrid.test(self.done, tx, ty):
            self.cover(bitgrid.single(self.done.shape, tx, ty))
        return bitgrid.test(self.bits, x, y)


# An obstacle is tested on a tile's cells (tiles.TILE x TILE) only when it can block one of
# them (see _blocked_jit). Its bounding disc gets a slack of _SLACK times the largest coordinate:
# far more than the per-cell tests' rounding (~1e-12 m at a few km), far less than a cell.
_SLACK = 1e-6
_TILE = tiles.TILE


def _bounding_discs(circles: np.ndarray, pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """(C + K, 4): for each circle, then each convex piece (vertices, outward normals, offsets),
    a centre (x, y), the radius of a disc there that holds it and of one that it holds."""
    rows = [(x, y, r, r) for x, y, r in circles]
    for v, normal, offset in pieces:
        c = v.mean(axis=0)  # inside a convex piece: every edge's line is at least ``inner`` away
        inner = float(((offset - normal @ c) / np.hypot(normal[:, 0], normal[:, 1])).min())
        rows.append((c[0], c[1], float(np.hypot(*(v - c).T).max()), max(inner, 0.0)))
    return np.array(rows, dtype=float).reshape(-1, 4)


_blocked_jit = None  # None: the numpy masks (tests and the numpy-only bench set it so)
if numba is not None:
    @numba.njit(cache=True, nogil=True, inline="always")
    def _set_tile_rows(bits, x0, x1, y0, y1):
        """Every cell of the tile set (a tile's row lies in one word)."""
        row = ((np.uint64(1) << np.uint64(x1 - x0)) - np.uint64(1)) << np.uint64(x0 & 63)
        for iy in range(y0, y1):
            bits[iy, x0 >> 6] |= row

    @numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
    def _blocked_tile(bits, xs, ys, x0, x1, y0, y1, px, py, circles, start, v, normal, offset, outside, cand, m):
        """The numpy mask's tests on the tile's cells, for the candidate obstacles only."""
        n_c = len(circles)
        for iy in range(y0, y1):
            qy = ys[iy]
            dy = qy - py
            row = np.uint64(0)
            for ix in range(x0, x1):
                qx = xs[ix]
                dx = qx - px
                len2 = dx * dx + dy * dy
                blocked = False
                for i in range(m):
                    o = cand[i]
                    if o < n_c:
                        cx, cy, r = circles[o, 0], circles[o, 1], circles[o, 2]
                        ex, ey = qx - cx, qy - cy
                        wx, wy = cx - px, cy - py
                        along = wx * dx + wy * dy
                        cross = dx * wy - dy * wx
                        if ex * ex + ey * ey < r * r or (along > 0 and along < len2 and cross * cross < r * r * len2):
                            blocked = True
                            break
                        continue
                    k = o - n_c
                    separated = False
                    for j in range(start[k], start[k + 1]):
                        if outside[j] and normal[j, 0] * qx + normal[j, 1] * qy > offset[j]:
                            separated = True
                            break
                    if not separated:
                        above = below = True
                        for j in range(start[k], start[k + 1]):
                            cross = dx * (v[j, 1] - py) - dy * (v[j, 0] - px)
                            above = above and cross > 0
                            below = below and cross < 0
                        if not (above or below):
                            blocked = True
                            break
                if blocked:
                    row |= np.uint64(1) << np.uint64(ix - x0)
            bits[iy, x0 >> 6] |= row << np.uint64(x0 & 63)

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _blocked_jit(bits, done, need, xs, ys, px, py, circles, start, v, normal, offset, outside, bounds, slack):
        """SightShadows.blocked_from per cell, packed into ``bits`` on the tiles of ``need`` not
        in ``done`` (tile maps, :mod:`bitgrid`), which it adds to ``done``: circles (C, 3) as
        (x, y, r), convex pieces k as rows start[k]:start[k + 1] of v, normal, offset;
        ``outside``: p outside edge j; ``bounds``: :func:`_bounding_discs` (obstacle o: circle o,
        else piece o - C).

        Tile by tile, with the segment from p to the tile's centre: a segment from p to any cell
        q of the tile lies within the tile's half-diagonal of it (its point at fraction s is
        s |q - centre| from the one at s of the other). So an obstacle whose outer disc that
        segment misses by more than the half-diagonal plus ``slack`` is farther than ``slack``
        from every cell's segment: the numpy mask's per-cell tests could not find it blocking,
        and only the other obstacles (candidates) are tested, cell by cell. And when it passes
        deeper than that into a candidate's inner disc, every cell's segment runs more than
        ``slack`` deep inside the obstacle: the per-cell tests find each one blocked, beyond
        their rounding (no edge of a piece has both ends outside, and its vertices lie on both
        sides of the segment's line), and the whole tile is."""
        n_c, n_k = len(circles), len(start) - 1
        inside = False  # p inside a circle: everything is blocked
        for c in range(n_c):
            wx, wy, r = circles[c, 0] - px, circles[c, 1] - py, circles[c, 2]
            inside = inside or wx * wx + wy * wy < r * r
        cand = np.empty(n_c + n_k, dtype=np.int64)
        t = _TILE
        for ty in range(need.shape[0]):
            y0 = ty * t
            y1 = min(y0 + t, len(ys))
            for wt in range(need.shape[1]):
                todo = need[ty, wt] & ~done[ty, wt]
                for b in range(64):
                    if not (todo >> np.uint64(b)) & np.uint64(1):
                        continue
                    x0 = (wt * 64 + b) * t
                    x1 = min(x0 + t, len(xs))
                    if inside:
                        _set_tile_rows(bits, x0, x1, y0, y1)
                        continue
                    mx, my = 0.5 * (xs[x0] + xs[x1 - 1]), 0.5 * (ys[y0] + ys[y1 - 1])  # the tile's centre
                    half = 0.5 * math.hypot(xs[x1 - 1] - xs[x0], ys[y1 - 1] - ys[y0])
                    dx, dy = mx - px, my - py
                    len2 = dx * dx + dy * dy
                    m = 0
                    full = False
                    for o in range(n_c + n_k):  # the point of segment p -> centre nearest the discs' centre
                        wx, wy = bounds[o, 0] - px, bounds[o, 1] - py
                        u = 0.0 if len2 == 0.0 else min(max((wx * dx + wy * dy) / len2, 0.0), 1.0)
                        ex, ey = wx - u * dx, wy - u * dy
                        e2 = ex * ex + ey * ey
                        reach, deep = bounds[o, 2] + half + slack, bounds[o, 3] - half - slack
                        if deep > 0.0 and e2 < deep * deep:
                            full = True
                            break
                        if e2 <= reach * reach:
                            cand[m] = o
                            m += 1
                    if full:
                        _set_tile_rows(bits, x0, x1, y0, y1)
                    elif m:
                        _blocked_tile(bits, xs, ys, x0, x1, y0, y1, px, py, circles, start, v, normal, offset,
                                      outside, cand, m)
                done[ty, wt] |= todo  # after its tiles' bits: a tile marked done is never half-written
