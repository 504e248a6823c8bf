"""Boolean grids packed 64 cells to a word, for the space-time wavefront.

Row y of a (ny, nx) bool mask becomes ceil(nx / 64) uint64 words, column x at bit x % 64 of
word x // 64 (bits beyond nx are 0). A one-cell shift along x is a word shift with the carry
from the neighbouring word, so dilating a 360 x 360 grid is a dozen numpy operations on
360 x 6 words instead of on 130 000 booleans.
"""

from __future__ import annotations

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


def dilate_within(m: np.ndarray, free: np.ndarray, moves: tuple[int, ...]) -> np.ndarray:
    """``m`` dilated once per entry of ``moves`` (4 or 8), masked by ``free`` after each: a new
    array. Compiled when numba is installed (bit operations: the same words either way; the
    numpy loop spends most of its time in per-call overhead on a few thousand words)."""
    if _dilate_within_jit is not None:
        return _dilate_within_jit(m, free, np.asarray(moves, dtype=np.int64))
    for kind in moves:
        m = dilate(m, kind) & free
    return m


_dilate_within_jit = None
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
