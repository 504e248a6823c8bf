"""Tile maps: which TILE x TILE tiles of a grid a packed set (:mod:`bitgrid`) touches, packed the
same way (a bit per tile, rows of tiles), so that masks are computed only on the tiles a search reaches.

A tile's row of cells is one byte of a packed word (TILE = 8), so a word's tiles are its non-zero
bytes: ``tiles_of(bits)``, ``spills(bits, done)`` (a set cell outside the tiles of ``done``),
``missing(need, done)`` (a tile of ``need`` not in ``done``).
"""

from __future__ import annotations

import numpy as np

from companion.planning.coordination.bitgrid import TILE, pack

try:
    import numba
except ImportError:  # the numpy tile maps run instead (the ``fast`` extra brings numba)
    numba = None

__all__ = ["TILE", "all_tiles", "missing", "spills", "tile_shape", "tiles_of"]


def tile_shape(ny: int, nx: int) -> tuple[int, int]:
    """The shape of the packed tile map of a (ny, nx) grid: a bit per TILE x TILE tile, in rows of tiles."""
    return -(-ny // TILE), -(-nx // (64 * TILE))


def all_tiles(ny: int, nx: int) -> np.ndarray:
    """The packed tile map with every tile of a (ny, nx) grid."""
    return pack(np.ones((-(-ny // TILE), -(-nx // TILE)), dtype=bool))


def tiles_of(bits: np.ndarray) -> np.ndarray:
    """The packed tile map of the tiles holding a set bit of packed ``bits``."""
    if _tiles_of_jit is not None:
        return _tiles_of_jit(bits)
    ny, words = bits.shape
    as_bytes = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)  # byte j: the cells of tile j
    rows = np.zeros((-(-ny // TILE) * TILE, words * 8), dtype=bool)
    rows[:ny] = as_bytes != 0
    return pack(rows.reshape(-1, TILE, words * 8).any(axis=1))


def spills(bits: np.ndarray, done: np.ndarray) -> bool:
    """Whether packed ``bits`` has a set bit outside the tiles of tile map ``done``."""
    if _spills_jit is not None:
        return _spills_jit(bits, done)
    return missing(tiles_of(bits), done)


def missing(need: np.ndarray, done: np.ndarray) -> bool:
    """Whether tile map ``need`` has a tile that ``done`` has not."""
    if _missing_jit is not None:
        return _missing_jit(need, done)
    return bool((need & ~done).any())


_tiles_of_jit = _spills_jit = _missing_jit = None
if numba is not None:
    @numba.njit(cache=True, nogil=True, inline="always")
    def _word_tiles(v):
        """The 8 tiles a word's bytes fall in, as the 8 low bits: each byte's OR folded into its
        lowest bit, those gathered into one byte by a multiplication (no two land on one place)."""
        v |= v >> np.uint64(4)
        v |= v >> np.uint64(2)
        v |= v >> np.uint64(1)
        return ((v & np.uint64(0x0101010101010101)) * np.uint64(0x0102040810204080)) >> np.uint64(56)

    @numba.njit(cache=True, nogil=True)
    def _tiles_of_jit(bits):
        ny, words = bits.shape
        out = np.zeros((-(-ny // 8), -(-words // 8)), dtype=np.uint64)
        for y in range(ny):
            for w in range(words):
                if bits[y, w]:
                    out[y >> 3, w >> 3] |= _word_tiles(bits[y, w]) << np.uint64(8 * (w & 7))
        return out

    @numba.njit(cache=True, nogil=True)
    def _spills_jit(bits, done):
        ny, words = bits.shape
        for y in range(ny):
            for w in range(words):
                if bits[y, w] and _word_tiles(bits[y, w]) & ~(done[y >> 3, w >> 3] >> np.uint64(8 * (w & 7))):
                    return True
        return False

    @numba.njit(cache=True, nogil=True)
    def _missing_jit(need, done):
        for ty in range(need.shape[0]):
            for j in range(need.shape[1]):
                if need[ty, j] & ~done[ty, j]:
                    return True
        return False
