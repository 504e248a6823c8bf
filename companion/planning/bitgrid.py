"""Boolean grids packed 64 cells to a word, for the space-time wavefront.

Row y of a (ny, nx) bool mask becomes ceil(nx / 64) uint64 words, column x at bit x % 64 of
word x // 64 (bits beyond nx are 0). A one-cell shift along x is a word shift with the carry
from the neighbouring word, so dilating a 360 x 360 grid is a dozen numpy operations on
360 x 6 words instead of on 130 000 booleans.
"""

from __future__ import annotations

import numpy as np


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
