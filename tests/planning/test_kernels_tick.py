"""The compiled heading critic over a goal window, the compiled obstacle rule + distance critic and
the compiled sight frame (the compiled backend's) give bit for bit the numbers of their numpy twins,
on random rollouts, goal windows and clearances (ties, points on the goals, already inside)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.planning.dwa import LocalGoals
from companion.planning.dwa.backend import COMPILED, NUMPY
from tests.planning.test_kernels import worlds

needs_numba = pytest.mark.skipif(COMPILED is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the last bit (the sign of zero included) and of the same dtype."""
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


@st.composite
def windows(draw):
    """Rollouts (S, K + 1) fanning out from the origin, and a window of 1-4 goals near them,
    the last one the station or not, some goals on rollout points."""
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    n_s, n_k = draw(st.integers(1, 40)), draw(st.integers(2, 24))
    step = draw(st.sampled_from([0.0, 2.0, 5.0]))
    turn = rng.uniform(-0.3, 0.3, n_s)[:, None] * np.arange(n_k)
    px = np.cumsum(step * np.cos(turn), axis=1) - step
    py = np.cumsum(step * np.sin(turn), axis=1)
    px[:, 0] = py[:, 0] = 0.0
    count = draw(st.integers(1, 4))
    nodes = rng.uniform(-80.0, 120.0, (count, 2))
    if draw(st.booleans()):  # a goal exactly on a rollout point
        nodes[0] = px[rng.integers(n_s), rng.integers(n_k)], py[0, -1]
    prev = (float(rng.uniform(-50.0, 0.0)), float(rng.uniform(-50.0, 50.0)))
    goals = LocalGoals(nodes, prev, draw(st.sampled_from([0.0, 10.0, 30.0])), draw(st.sampled_from([5.0, 20.0])),
                       ends_at_station=draw(st.booleans()))
    final = rng.uniform(-4.0, 4.0, n_s)
    final[::5] = 0.0
    return px, py, final, goals, draw(st.sampled_from([0.0, 5.0]))


@needs_numba
@settings(max_examples=200, deadline=None)
@given(windows())
def test_heading_window_kernel_matches_numpy(case) -> None:
    px, py, final, goals, soonest = case
    ex, ey = px[:, -1], py[:, -1]
    got = COMPILED.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), px, py, False, soonest)
    reference = NUMPY.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), px, py, False, soonest)
    assert same_bits(got, reference)


@st.composite
def clearances(draw):
    """Clearances (O, S * (K + 1)) of S rollouts to O obstacles: outside every one at the pose or
    inside some, with exact zeros, the -1e-9 slack's edge and ties."""
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    n_o, n_s, n_k = draw(st.integers(1, 6)), draw(st.integers(1, 40)), draw(st.integers(2, 24))
    clear = rng.uniform(-15.0, 40.0, (n_o, n_s * n_k))
    picks = rng.integers(0, clear.size, clear.size // 7)
    clear.flat[picks] = rng.choice([0.0, -0.0, -1e-9, -2e-9, 5.0, 12.0], len(picks))
    if draw(st.booleans()):
        clear[:, 0] = np.abs(clear[:, 0])  # the pose outside every inflated obstacle
    saturation = draw(st.sampled_from([0.0, 10.0, 12.0, 50.0]))
    return clear, (n_s, n_k), saturation


@needs_numba
@settings(max_examples=200, deadline=None)
@given(clearances())
def test_obstacle_kernel_matches_numpy(case) -> None:
    clear, shape, saturation = case
    ok, distance = COMPILED.obstacle_and_distance(clear, shape, saturation)
    ref_ok, ref_distance = NUMPY.obstacle_and_distance(clear, shape, saturation)
    assert same_bits(ok, ref_ok) and same_bits(distance, ref_distance)


@needs_numba
@settings(max_examples=60, deadline=None)
@given(worlds(), st.integers(0, 2**31), st.integers(1, 130), st.floats(-300.0, 300.0), st.floats(-300.0, 300.0),
       st.floats(0.0, 20.0))
def test_sight_frame_kernel_matches_numpy_on_a_subset(snap, seed: int, n: int, qx: float, qy: float,
                                                      t_s: float) -> None:
    """The sightline critic over the obstacles a mask keeps (as sightline_term culls them)."""
    rng = np.random.default_rng(seed)
    ex, ey = rng.uniform(-400.0, 400.0, (2, n))
    keep = rng.random(snap.count) < 0.6
    keep[rng.integers(snap.count)] = True  # sightline_term keeps at least one
    got = COMPILED.sightline_depths(ex, ey, (qx, qy), t_s, snap, keep)
    assert same_bits(got, NUMPY.sightline_depths(ex, ey, (qx, qy), t_s, snap, keep))
