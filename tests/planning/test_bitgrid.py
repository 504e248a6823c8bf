"""The packed-bit dilation of the space-time wavefront: compiled and numpy paths give the same
words, and both agree with a plain boolean dilation."""

import contextlib
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from companion.planning.coordination import bitgrid, tiles


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


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
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


def _numpy_paths():
    """bitgrid's compiled kernels off inside the block."""
    import contextlib

    @contextlib.contextmanager
    def off():
        names = [(bitgrid, n) for n in ("_farther_jit", "_nearest_jit", "_grow_jit", "_dilate_within_jit",
                                        "_allowed_jit", "_within_any_jit")]
        names += [(tiles, n) for n in ("_tiles_of_jit", "_spills_jit", "_missing_jit")]
        saved = [getattr(m, n) for m, n in names]
        for m, n in names:
            setattr(m, n, None)
        try:
            yield
        finally:
            for (m, n), kernel in zip(names, saved):
                setattr(m, n, kernel)
    return off()


_coords = st.floats(-2000.0, 2000.0, allow_nan=False)


@st.composite
def _cells(draw):
    """Cell centres of a grid (some rows and columns beyond one word) and a few points, some on
    cell centres (ties between cells) and some on each other."""
    nx, ny = draw(st.integers(1, 150)), draw(st.integers(1, 12))
    x0, y0, res = draw(_coords), draw(_coords), draw(st.floats(0.5, 40.0))
    xs, ys = x0 + res * (np.arange(nx) + 0.5), y0 + res * (np.arange(ny) + 0.5)
    cell = st.tuples(st.sampled_from(list(xs)), st.sampled_from(list(ys)))
    points = draw(st.lists(st.one_of(st.tuples(_coords, _coords), cell), min_size=1, max_size=3))
    return xs, ys, [(float(x), float(y)) for x, y in points]


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
@settings(max_examples=80, deadline=None)
@given(_cells(), st.floats(0.0, 1.0), st.booleans(), st.integers(0, 2**32 - 1))
def test_compiled_distance_masks_and_nearest_cells_equal_the_numpy_ones(cells, q, strict, seed):
    xs, ys, points = cells
    d2 = float(np.quantile(bitgrid.distance2(xs, ys, points[0]), q))  # a threshold some cells tie with
    with _numpy_paths():
        want_far = bitgrid.farther(xs, ys, points[0], d2, strict)
        want_within = bitgrid.within(xs, ys, points[0], d2)
    got_far = bitgrid.farther(xs, ys, points[0], d2, strict)
    assert got_far.dtype == want_far.dtype and np.array_equal(got_far, want_far)
    got_within = bitgrid.within(xs, ys, points[0], d2)
    assert got_within.dtype == want_within.dtype and np.array_equal(got_within, want_within)
    rng = np.random.default_rng(seed)
    bits = bitgrid.pack(rng.random((len(ys), len(xs))) < rng.choice([0.01, 0.3, 1.0]))
    if not bits.any():
        bits = bitgrid.single(bits.shape, len(xs) - 1, len(ys) - 1)
    with _numpy_paths():
        want = bitgrid.nearest(bits, xs, ys, points)
    got = bitgrid.nearest(bits, xs, ys, points)
    assert got == want and type(got[0]) is type(want[0]) and all(type(v) is int for v in got[1])


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
@settings(max_examples=60, deadline=None)
@given(ny=st.integers(1, 40), nx=st.integers(1, 200), seed=st.integers(0, 2**32 - 1),
       moves=st.lists(st.sampled_from([4, 8]), min_size=1, max_size=6), density=st.sampled_from([0.0, 0.002, 0.05]))
def test_compiled_growth_equals_the_numpy_growth(ny, nx, seed, moves, density):
    """grow: the rows a set can reach, dilated; empty sets and sets at the edges too."""
    rng = np.random.default_rng(seed)
    bits = bitgrid.pack(rng.random((ny, nx)) < density)
    free = bitgrid.pack(rng.random((ny, nx)) < 0.8)
    with _numpy_paths():
        want = bitgrid.grow(bits, free, tuple(moves))
    assert np.array_equal(bitgrid.grow(bits, free, tuple(moves)), want)


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
@settings(max_examples=80, deadline=None)
@given(_cells(), st.floats(0.0, 1.0), st.sampled_from([None, "near", "inf"]), st.integers(0, 2**32 - 1))
def test_compiled_allowed_mask_equals_the_masks_one_by_one(cells, q, mode, seed):
    """bitgrid.allowed in one compiled pass: the words of free & far masks & (shadow [| farther])."""
    xs, ys, points = cells
    rng = np.random.default_rng(seed)
    shape = (len(ys), len(xs))
    free = bitgrid.pack(rng.random(shape) < 0.9)
    far = np.stack([bitgrid.pack(rng.random(shape) < 0.8) for _ in range(2)])
    shadows = np.stack([bitgrid.pack(rng.random(shape) < 0.5) for _ in points])
    near2 = {None: None, "inf": math.inf, "near": float(np.quantile(bitgrid.distance2(xs, ys, points[0]), q))}[mode]
    pts = np.array(points, dtype=float)
    with _numpy_paths():
        want = bitgrid.allowed(free, xs, ys, far, shadows, pts, near2)
    assert np.array_equal(bitgrid.allowed(free, xs, ys, far, shadows, pts, near2), want)
    assert np.array_equal(bitgrid.allowed(free, xs, ys, far[:0], shadows[:0], pts[:0], near2), free)
    some = tiles.tiles_of(bitgrid.pack(rng.random(shape) < 0.01))  # only these tiles' rows are asked for
    rows = np.repeat(bitgrid.unpack(some, -(-len(xs) // tiles.TILE)).any(axis=1), tiles.TILE)[:len(ys)]
    assert np.array_equal(bitgrid.allowed(free, xs, ys, far, shadows, pts, near2, some)[rows], want[rows])


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
@settings(max_examples=80, deadline=None)
@given(_cells(), st.floats(0.0, 1.0))
def test_compiled_cells_within_any_point_equal_the_masks_one_by_one(cells, q):
    xs, ys, points = cells
    d2 = float(np.quantile(bitgrid.distance2(xs, ys, points[-1]), q))  # a threshold some cells tie with
    pts = np.array(points, dtype=float)
    with _numpy_paths():
        want = bitgrid.within_any(xs, ys, pts, d2)
    assert np.array_equal(bitgrid.within_any(xs, ys, pts, d2), want)
    union = np.zeros_like(want)
    for xy in points:
        union |= bitgrid.pack(bitgrid.distance2(xs, ys, xy) <= d2)
    assert np.array_equal(want, union)


@settings(max_examples=80, deadline=None)
@given(ny=st.integers(1, 40), nx=st.integers(1, 700), seed=st.integers(0, 2**32 - 1),
       density=st.sampled_from([0.0, 0.001, 0.02, 0.5]))
def test_tile_maps_hold_the_tiles_of_the_set_cells_on_either_path(ny, nx, seed, density):
    """tiles_of: the TILE x TILE tiles with a set cell; spills: a set cell outside a tile map; missing:
    a tile of one map not in another. Compiled and numpy paths, against a plain boolean tiling."""
    rng = np.random.default_rng(seed)
    mask = rng.random((ny, nx)) < density
    t = tiles.TILE
    padded = np.zeros((-(-ny // t) * t, -(-nx // t) * t), dtype=bool)
    padded[:ny, :nx] = mask
    want = bitgrid.pack(padded.reshape(padded.shape[0] // t, t, -1, t).any(axis=(1, 3)))
    some = want & bitgrid.pack(rng.random((padded.shape[0] // t, padded.shape[1] // t)) < 0.5)
    assert want.shape == tiles.tile_shape(ny, nx) == tiles.all_tiles(ny, nx).shape
    for numpy_only in (False, True):
        with _numpy_paths() if numpy_only else contextlib.nullcontext():
            bits = bitgrid.pack(mask)
            assert np.array_equal(tiles.tiles_of(bits), want)
            assert not tiles.spills(bits, want) and not tiles.spills(bits, tiles.all_tiles(ny, nx))
            assert tiles.spills(bits, some) == bool((want & ~some).any()) == tiles.missing(want, some)
            assert not tiles.missing(want, tiles.all_tiles(ny, nx))


@pytest.mark.skipif(bitgrid.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
@settings(max_examples=80, deadline=None)
@given(ny=st.integers(1, 30), nx=st.integers(1, 150), seed=st.integers(0, 2**32 - 1),
       moves=st.lists(st.sampled_from([4, 8]), min_size=1, max_size=6), density=st.sampled_from([0.05, 0.3, 0.9]))
def test_compiled_backtrack_step_equals_the_numpy_step(ny, nx, seed, moves, density):
    """step_back: the predecessor deepest in the layer, then the nearest, then the first in row
    order (ties are common on dense layers); none when no cell of the layer reaches the cell."""
    from companion.planning.coordination import backtrack
    rng = np.random.default_rng(seed)
    layer = bitgrid.pack(rng.random((ny, nx)) < density)
    free = rng.random((ny, nx)) < 0.85
    cell = (int(rng.integers(nx)), int(rng.integers(ny)))
    free[cell[1], cell[0]] = True
    m = np.asarray(moves, dtype=np.int64)
    saved, backtrack._step_back_jit = backtrack._step_back_jit, None
    try:
        want = backtrack.step_back(layer, free, cell, m)
    finally:
        backtrack._step_back_jit = saved
    assert backtrack.step_back(layer, free, cell, m) == want
