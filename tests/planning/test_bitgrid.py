"""The packed-bit dilation of the space-time wavefront: compiled and numpy paths give the same
words, and both agree with a plain boolean dilation."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from companion.planning import bitgrid


def _bool_dilate(mask: np.ndarray, kind: int) -> np.ndarray:
    """The reference: a boolean 4- or 8-neighbour dilation, no packing."""
    out = mask.copy()
    out[1:, :] |= mask[:-1, :]
    out[:-1, :] |= mask[1:, :]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    if kind == 8:
        out[1:, 1:] |= mask[:-1, :-1]
        out[1:, :-1] |= mask[:-1, 1:]
        out[:-1, 1:] |= mask[1:, :-1]
        out[:-1, :-1] |= mask[1:, 1:]
    return out


@settings(max_examples=60, deadline=None)
@given(ny=st.integers(1, 20), nx=st.integers(1, 200), seed=st.integers(0, 2**32 - 1),
       moves=st.lists(st.sampled_from([4, 8]), min_size=1, max_size=6))
def test_dilate_within_matches_a_boolean_dilation(ny, nx, seed, moves):
    rng = np.random.default_rng(seed)
    mask = rng.random((ny, nx)) < 0.05
    free = rng.random((ny, nx)) < 0.8
    want = mask
    for kind in moves:
        want = _bool_dilate(want, kind) & free
    got = bitgrid.dilate_within(bitgrid.pack(mask), bitgrid.pack(free), tuple(moves))
    assert np.array_equal(bitgrid.unpack(got, nx), want)


@pytest.mark.skipif(bitgrid.numba is None, reason="numba (the 'fast' extra) is not installed")
def test_compiled_and_numpy_dilations_give_the_same_words():
    rng = np.random.default_rng(7)
    m = bitgrid.pack(rng.random((50, 300)) < 0.03)
    free = bitgrid.pack(rng.random((50, 300)) < 0.9)
    moves = (4, 8, 4, 8, 4)
    numpy_words = m
    for kind in moves:
        numpy_words = bitgrid.dilate(numpy_words, kind) & free
    before = m.copy()
    assert np.array_equal(bitgrid.dilate_within(m, free, moves), numpy_words)
    assert np.array_equal(m, before)  # the input is not touched
