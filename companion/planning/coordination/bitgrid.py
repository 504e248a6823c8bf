"""Boolean grids packed 64 cells to a word, for the space-time wavefront.

Row y of a (ny, nx) bool mask becomes ceil(nx / 64) uint64 words, column x at bit x % 64 of
word x // 64 (bits beyond nx are 0). A one-cell shift along x is a word shift with the carry
from the neighbouring word, so dilating a 360 x 360 grid is a dozen numpy operations on
360 x 6 words instead of on 130 000 booleans.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # the numpy dilation runs instead (the ``fast`` extra brings numba)
    numba = None


def pack(mask: np.ndarray) -> np.ndarray:
    """(ny, nx) bool -> (ny, ceil(nx / 64)) uint64."""
    ny, nx = mask.shape
    words = -(-nx // 64)
    padded = np.zeros((ny, words * 64), dtype=bool)
    padded[:, :nx] = mask
    return np.packbits(padded, axis=1, bitorder="little").view("<u8").astype(np.uint64, copy=False)


def unpack(bits: np.ndarray, nx: int) -> np.ndarray:
    """(ny, words) uint64 -> (ny, nx) bool."""
    as_bytes = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)
    return np.unpackbits(as_bytes, axis=1, bitorder="little")[:, :nx].astype(bool)


def test(bits: np.ndarray, x: int, y: int) -> bool:
    return bool((int(bits[y, x >> 6]) >> (x & 63)) & 1)


def single(shape_bits: tuple[int, int], x: int, y: int) -> np.ndarray:
    out = np.zeros(shape_bits, dtype=np.uint64)
    out[y, x >> 6] = np.uint64(1) << np.uint64(x & 63)
    return out


def distance2(xs: np.ndarray, ys: np.ndarray, xy: tuple[float, float]) -> np.ndarray:
    """(ny, nx): the squared distance from each cell centre (xs[ix], ys[iy]) to ``xy``."""
    return (xs[None, :] - xy[0]) ** 2 + (ys[:, None] - xy[1]) ** 2


def farther(xs: np.ndarray, ys: np.ndarray, xy: tuple[float, float], d2: float, strict: bool = True) -> np.ndarray:
    """Packed: the cells whose :func:`distance2` to ``xy`` is above ``d2`` (``strict``) or at
    least ``d2``. Compiled when numba is installed: the same sums, so the same bits."""
    if _farther_jit is not None:
        return _farther_jit(xs, ys, float(xy[0]), float(xy[1]), float(d2), strict)
    d = distance2(xs, ys, xy)
    return pack(d > d2 if strict else d >= d2)


def within(xs: np.ndarray, ys: np.ndarray, xy: tuple[float, float], d2: float) -> np.ndarray:
    """Packed: the cells whose :func:`distance2` to ``xy`` is at most ``d2`` (those not
    :func:`farther`, strictly)."""
    if _farther_jit is None:
        return pack(distance2(xs, ys, xy) <= d2)
    out = ~_farther_jit(xs, ys, float(xy[0]), float(xy[1]), float(d2), True)
    if len(xs) % 64:  # no bits beyond the grid
        out[:, -1] &= (np.uint64(1) << np.uint64(len(xs) % 64)) - np.uint64(1)
    return out


def nearest(bits: np.ndarray, xs: np.ndarray, ys: np.ndarray,
            points: list[tuple[float, float]]) -> tuple[float, tuple[int, int]]:
    """The least :func:`distance2` to the nearest of ``points`` over the cells of packed ``bits``
    (not empty), and its cell (ix, iy): the first in row order on ties."""
    if _nearest_jit is not None:
        d2, ix, iy = _nearest_jit(bits, xs, ys, np.array(points, dtype=float).reshape(-1, 2))
        return d2, (ix, iy)
    rows = np.flatnonzero(bits.any(axis=1))
    iy, ix = np.nonzero(unpack(bits[rows], len(xs)))
    iy = rows[iy]
    d2 = np.min([(xs[ix] - x) ** 2 + (ys[iy] - y) ** 2 for x, y in points], axis=0)
    i = int(np.argmin(d2))
    return float(d2[i]), (int(ix[i]), int(iy[i]))


TILE = 8  # cells per side of a tile (tiles.py): a tile's row of cells is one byte of a word

_ONE = np.uint64(1)
_TOP = np.uint64(63)


def dilate(m: np.ndarray, kind: int) -> np.ndarray:
    """One 4- or 8-neighbour dilation (bits may spill past nx: mask with a free grid after)."""
    row = m | (m << _ONE) | (m >> _ONE)
    row[:, 1:] |= m[:, :-1] >> _TOP
    row[:, :-1] |= m[:, 1:] << _TOP
    src = row if kind == 8 else m
    out = row.copy()
    out[1:, :] |= src[:-1, :]
    out[:-1, :] |= src[1:, :]
    return out


def grow(bits: np.ndarray, free: np.ndarray, moves: tuple[int, ...]) -> np.ndarray:
    """:func:`dilate_within` on the rows that can be reached at all (those of ``bits`` and
    ``len(moves)`` more each side): a new array, the other rows empty."""
    if _grow_jit is not None:
        return _grow_jit(bits, free, np.asarray(moves, dtype=np.int64))
    rows = np.flatnonzero(bits.any(axis=1))
    out = np.zeros_like(bits)
    if not rows.size:
        return out
    r = len(moves)
    y0, y1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, bits.shape[0])
    out[y0:y1] = dilate_within(bits[y0:y1], free[y0:y1], moves)
    return out


def dilate_within(m: np.ndarray, free: np.ndarray, moves: tuple[int, ...]) -> np.ndarray:
    """``m`` dilated once per entry of ``moves`` (4 or 8), masked by ``free`` after each: a new
    array. Compiled when numba is installed (bit operations: the same words either way; the
    numpy loop spends most of its time in per-call overhead on a few thousand words)."""
    if _dilate_within_jit is not None:
        return _dilate_within_jit(m, free, np.asarray(moves, dtype=np.int64))
    for kind in moves:
        m = dilate(m, kind) & free
    return m


def allowed(free: np.ndarray, xs: np.ndarray, ys: np.ndarray, far: np.ndarray, shadows: np.ndarray,
            points: np.ndarray, near2: float | None, tiles: np.ndarray | None = None) -> np.ndarray:
    """Packed: ``free`` and every mask of ``far`` (k, ny, words), and for each mask of ``shadows``
    (m, ny, words) with its point ``points[i]``: in it (``near2`` None), or in it or farther
    than ``near2`` from the point (:func:`farther`, strictly). One compiled pass when numba is
    installed: the same sums and bit operations as the masks one by one, so the same bits.
    ``tiles``: a tile map (:mod:`tiles`); the result is then only for the rows of its tiles (the
    compiled pass leaves the others empty, the numpy one computes them too)."""
    if _allowed_jit is not None:
        return _allowed_jit(free, far, shadows, xs, ys, points, -1.0 if near2 is None else float(near2),
                            near2 is not None, np.ones((-(-free.shape[0] // TILE), 1), dtype=np.uint64) if tiles is None else tiles)
    ok = free.copy()
    for mask in far:
        ok &= mask
    for mask, xy in zip(shadows, points):
        ok &= mask if near2 is None else mask | farther(xs, ys, (float(xy[0]), float(xy[1])), near2)
    return ok


def within_any(xs: np.ndarray, ys: np.ndarray, points: np.ndarray, d2: float) -> np.ndarray:
    """Packed: the cells within ``d2`` (:func:`within`) of any of ``points`` (n, 2); one compiled
    pass when numba is installed, the same bits as the masks one by one."""
    if _within_any_jit is not None:
        return _within_any_jit(xs, ys, points, float(d2))
    out = np.zeros((len(ys), -(-len(xs) // 64)), dtype=np.uint64)
    for x, y in points:
        out |= within(xs, ys, (float(x), float(y)), d2)
    return out


_dilate_within_jit = _grow_jit = _allowed_jit = _within_any_jit = None
if numba is not None:
    @numba.njit(cache=True, nogil=True)
    def _dilate_within_jit(m, free, moves):
        rows, words = m.shape
        one, top = np.uint64(1), np.uint64(63)
        cur = m.copy()
        row = np.empty_like(m)
        nxt = np.empty_like(m)
        for kind in moves:
            for y in range(rows):
                for w in range(words):
                    v = cur[y, w]
                    r = v | (v << one) | (v >> one)
                    if w > 0:
                        r |= cur[y, w - 1] >> top
                    if w < words - 1:
                        r |= cur[y, w + 1] << top
                    row[y, w] = r
            src = row if kind == 8 else cur
            for y in range(rows):
                for w in range(words):
                    o = row[y, w]
                    if y > 0:
                        o |= src[y - 1, w]
                    if y < rows - 1:
                        o |= src[y + 1, w]
                    nxt[y, w] = o & free[y, w]
            cur, nxt = nxt, cur
        return cur

    @numba.njit(cache=True, nogil=True)
    def _grow_jit(bits, free, moves):
        first = last = -1
        for y in range(bits.shape[0]):
            for w in range(bits.shape[1]):
                if bits[y, w]:
                    first = y if first < 0 else first
                    last = y
                    break
        out = np.zeros_like(bits)
        if first < 0:
            return out
        r = len(moves)
        y0, y1 = max(first - r, 0), min(last + r + 1, bits.shape[0])
        out[y0:y1] = _dilate_within_jit(bits[y0:y1], free[y0:y1], moves)
        return out


_farther_jit = _nearest_jit = None
if numba is not None:
    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _farther_jit(xs, ys, x, y, d2, strict):
        # xs ascend (cell centres), so (xs - x) ** 2 falls over xs < x and rises after (rounding is
        # monotone), and so does each row's sum: the cells farther are a prefix and a suffix of
        # the row, found by bisection with the very sums a cell-by-cell test compares.
        nx = len(xs)
        out = np.zeros((len(ys), -(-nx // 64)), dtype=np.uint64)
        ax = (xs - x) ** 2
        centre = np.searchsorted(xs, x)
        for iy in range(len(ys)):
            ay = (ys[iy] - y) ** 2
            a, b = 0, centre  # the first cell before the centre that is not farther
            while a < b:
                m = (a + b) // 2
                d = ax[m] + ay
                if d > d2 if strict else d >= d2:
                    a = m + 1
                else:
                    b = m
            _set_bits(out[iy], 0, a)
            a, b = centre, nx  # the first cell from the centre on that is farther
            while a < b:
                m = (a + b) // 2
                d = ax[m] + ay
                if d > d2 if strict else d >= d2:
                    b = m
                else:
                    a = m + 1
            _set_bits(out[iy], a, nx)
        return out

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _allowed_jit(free, far, shadows, xs, ys, points, near2, near, tiles):
        ny, words = free.shape
        rows = np.zeros(ny, dtype=np.bool_)  # the rows of the tiles asked for
        for ty in range(tiles.shape[0]):
            for j in range(tiles.shape[1]):
                if tiles[ty, j]:
                    rows[ty * TILE:ty * TILE + TILE] = True
                    break
        out = np.zeros_like(free)
        for iy in range(ny):
            if rows[iy]:
                for w in range(words):
                    v = free[iy, w]
                    for j in range(far.shape[0]):
                        v &= far[j, iy, w]
                    out[iy, w] = v
        nx = len(xs)
        full = ~np.uint64(0)
        for i in range(shadows.shape[0]):
            if not near:
                for iy in range(ny):
                    if rows[iy]:
                        for w in range(words):
                            out[iy, w] &= shadows[i, iy, w]
                continue
            x, y = points[i, 0], points[i, 1]
            ax = (xs - x) ** 2  # as _farther_jit: the cells not farther are a span of each row
            centre = np.searchsorted(xs, x)
            span = np.zeros(words, dtype=np.uint64)
            for iy in range(ny):
                if not rows[iy]:
                    continue
                lo, hi = _within_span(ax, (ys[iy] - y) ** 2, centre, nx, near2)
                if lo >= hi:
                    continue
                span[:] = 0
                _set_bits(span, lo, hi)  # within near2: there the shadow must hold
                for w in range(lo >> 6, ((hi - 1) >> 6) + 1):
                    out[iy, w] &= shadows[i, iy, w] | (full ^ span[w])
        return out

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _within_any_jit(xs, ys, points, d2):
        nx = len(xs)
        out = np.zeros((len(ys), -(-nx // 64)), dtype=np.uint64)
        for i in range(points.shape[0]):
            ax = (xs - points[i, 0]) ** 2
            centre = np.searchsorted(xs, points[i, 0])
            for iy in range(len(ys)):
                lo, hi = _within_span(ax, (ys[iy] - points[i, 1]) ** 2, centre, nx, d2)
                _set_bits(out[iy], lo, hi)
        return out

    @numba.njit(cache=True, nogil=True, inline="always")
    def _within_span(ax, ay, centre, nx, d2):
        """The cells lo .. hi - 1 of a row whose sum ax + ay is at most d2 (a span: ax falls, then
        rises), by bisection as in _farther_jit (strict)."""
        if ay > d2:  # ax >= 0: every cell of the row is farther
            return 0, 0
        a, b = 0, centre
        while a < b:
            m = (a + b) // 2
            if ax[m] + ay > d2:
                a = m + 1
            else:
                b = m
        lo = a
        a, b = centre, nx
        while a < b:
            m = (a + b) // 2
            if ax[m] + ay > d2:
                b = m
            else:
                a = m + 1
        return lo, a

    @numba.njit(cache=True, nogil=True, inline="always")
    def _set_bits(row, a, b):
        """Bits a to b - 1 of the packed row set."""
        if a >= b:
            return
        full = ~np.uint64(0)
        wa, wb = a >> 6, (b - 1) >> 6
        lo = full << np.uint64(a & 63)
        hi = full >> np.uint64(63 - ((b - 1) & 63))
        if wa == wb:
            row[wa] |= lo & hi
            return
        row[wa] |= lo
        for w in range(wa + 1, wb):
            row[w] = full
        row[wb] |= hi

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _nearest_jit(bits, xs, ys, points):
        best, bx, by = math.inf, -1, -1
        for iy in range(bits.shape[0]):
            for w in range(bits.shape[1]):
                word = bits[iy, w]
                if word == 0:
                    continue
                for b8 in range(0, 64, 8):
                    if not (word >> np.uint64(b8)) & np.uint64(255):  # an empty byte: 8 cells skipped at once
                        continue
                    for b in range(b8, b8 + 8):
                        if not (word >> np.uint64(b)) & np.uint64(1):
                            continue
                        ix = w * 64 + b
                        d = math.inf
                        for j in range(len(points)):
                            d = min(d, (xs[ix] - points[j, 0]) ** 2 + (ys[iy] - points[j, 1]) ** 2)
                        if d < best:
                            best, bx, by = d, ix, iy
        return best, bx, by
