"""The numpy path's arctan2 has the C library's bits, as the compiled kernels do, on every CPU
(numpy's AVX-512 loops differ in the last bit; see companion.planning.dwa.libm)."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.planning.dwa import libm

coord = st.floats(-2e3, 2e3, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 300))
def test_arctan2_has_the_c_librarys_bits(seed: int, n: int) -> None:
    y, x = np.random.default_rng(seed).uniform(-1e3, 1e3, (2, n))
    x[::5] = 0.0  # on the axes and at the origin
    y[::7] = -0.0
    got = libm.arctan2(y, x)
    assert got.dtype == np.float64 and got.shape == (n,)
    assert np.array_equal(got.view(np.int64), np.array([math.atan2(b, a) for b, a in zip(y, x)]).view(np.int64))


@given(coord, st.lists(coord, min_size=1, max_size=9))
def test_arctan2_broadcasts_a_scalar_as_numpy_does(y: float, xs: list[float]) -> None:
    x = np.asarray(xs)
    assert libm.arctan2(y, x).shape == np.arctan2(y, x).shape
    assert list(libm.arctan2(y, x)) == [math.atan2(y, v) for v in xs]


def test_the_probe_sees_what_this_cpu_does() -> None:
    """The probe's answer is numpy's agreement on a large sample (it picks the elementwise path
    exactly where numpy's own would differ)."""
    y, x = np.random.default_rng(1).uniform(-5e2, 5e2, (2, 50_000))
    agrees = np.array_equal(np.arctan2(y, x), np.array([math.atan2(b, a) for b, a in zip(y, x)]))
    assert libm._numpy_agrees() == agrees
    assert (libm.arctan2 is np.arctan2) == agrees
