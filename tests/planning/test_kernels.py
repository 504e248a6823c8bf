"""The compiled backend's kernels (numba, the ``fast`` extra: geometry, culling, heading, the choice) give bit
for bit the numbers of the numpy backend's, over random worlds; and the clearance agrees with shapely."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.planning.dwa import DwaConfig, LocalGoals, ObstacleSnapshot
from companion.planning.dwa.backend import COMPILED, DEFAULT, NUMPY
from companion.planning.dwa.evaluate import Critics

needs_numba = pytest.mark.skipif(COMPILED is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")

coord = st.floats(-300.0, 300.0, allow_nan=False)
speed = st.sampled_from([0.0, 0.0, -4.0, 2.5])  # static as often as moving


@st.composite
def worlds(draw) -> ObstacleSnapshot:
    """Up to 3 circles and 3 convex or concave polygons (3-7 vertices: ragged edge counts are
    padded), some moving, margins 0-20 m."""
    circles = [(f"c{i}", draw(coord), draw(coord), draw(st.floats(1.0, 90.0)), draw(st.floats(0.0, 20.0)),
                draw(speed), draw(speed)) for i in range(draw(st.integers(0, 3)))]
    polygons = []
    for i in range(draw(st.integers(0, 3))):
        n = draw(st.integers(3, 7))
        # Star-shaped about the centre, vertices at least 10 deg apart: simple, no tiny edges.
        angles = np.radians(10.0 * np.sort(draw(st.lists(st.integers(0, 35), min_size=n, max_size=n, unique=True))))
        radii = np.array(draw(st.lists(st.floats(5.0, 120.0), min_size=n, max_size=n)))
        verts = np.c_[np.cos(angles) * radii, np.sin(angles) * radii] + (draw(coord), draw(coord))
        if shapely.Polygon(verts).is_valid:
            polygons.append((f"p{i}", verts, draw(st.floats(0.0, 20.0)), draw(speed), draw(speed)))
    snap = ObstacleSnapshot.build(circles, polygons)
    assume(snap.count)  # the planner never measures against nothing
    return snap


def points(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    px, py = rng.uniform(-400.0, 400.0, (2, n))
    return px, py, rng.uniform(0.0, 20.0, n)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the last bit, the sign of zero included."""
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


@needs_numba
@settings(max_examples=40, deadline=None)
@given(worlds(), st.integers(0, 2**31), st.integers(1, 3000))
def test_clearance_kernels_match_numpy_bit_for_bit(snap: ObstacleSnapshot, seed: int, n: int) -> None:
    px, py, t = points(seed, n)
    assert same_bits(COMPILED.inflated_clearance(px, py, t, snap), NUMPY.inflated_clearance(px, py, t, snap))
    if snap.poly_ids:
        assert same_bits(COMPILED.polygon_signed_distance(px, py, t, snap),
                         NUMPY.polygon_signed_distance(px, py, t, snap))


@needs_numba
@settings(max_examples=40, deadline=None)
@given(worlds(), st.integers(0, 2**31), st.integers(1, 130), coord, coord, st.floats(0.0, 20.0))
def test_sightline_kernels_match_numpy_bit_for_bit(snap: ObstacleSnapshot, seed: int, n: int, qx: float,
                                                   qy: float, t_s: float) -> None:
    ex, ey, _ = points(seed, n)
    for kernel in ("sightline_depths", "open_clearance"):
        got = getattr(COMPILED, kernel)(ex, ey, (qx, qy), t_s, snap)
        assert same_bits(got, getattr(NUMPY, kernel)(ex, ey, (qx, qy), t_s, snap)), kernel


@settings(max_examples=40, deadline=None)
@given(worlds(), st.integers(0, 2**31))
def test_clearance_is_the_distance_to_the_buffered_shape(snap: ObstacleSnapshot, seed: int) -> None:
    """Whichever kernels run: the clearance of a point is shapely's distance to the inflated
    (round-buffered) true shape, negative inside by the depth (static time 0)."""
    px, py, _ = points(seed, 40)
    got = DEFAULT.inflated_clearance(px, py, np.zeros(40), snap)
    shapes = [shapely.Point(xy).buffer(r, 256) for xy, r in zip(snap.circle_xy_m, snap.circle_radius_m)]
    shapes += [shapely.Polygon(snap.vertices(i)) for i in range(len(snap.poly_ids))]
    margins = np.concatenate([snap.circle_margin_m, snap.poly_margin_m])
    pts = shapely.points(px, py)
    for row, shape, margin in zip(got, shapes, margins):
        edge = shapely.distance(shape.exterior, pts)
        signed = np.where(shapely.contains(shape, pts), -edge, edge) - margin
        assert row == pytest.approx(signed, abs=0.05)  # 0.05 m: the circle's 256-segment buffer


@needs_numba
@settings(max_examples=60, deadline=None)
@given(worlds(), coord, coord, st.floats(0.0, 400.0), st.floats(0.0, 30.0),
       st.none() | st.tuples(coord, coord))
def test_culling_kernel_matches_numpy(snap: ObstacleSnapshot, x: float, y: float, reach: float, horizon: float,
                                      to_xy: tuple[float, float] | None) -> None:
    keep, kept = COMPILED.near_mask(snap, x, y, reach, horizon, to_xy)
    ref_keep, ref_kept = NUMPY.near_mask(snap, x, y, reach, horizon, to_xy)
    assert keep.dtype == ref_keep.dtype and np.array_equal(keep, ref_keep) and kept == ref_kept


@needs_numba
@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 130), coord, coord, st.floats(-20.0, 20.0))
def test_heading_kernel_matches_numpy(seed: int, n: int, tx: float, ty: float, heading: float) -> None:
    ex, ey, _ = points(seed, n)
    ex[::7] = tx  # straight above or below the target, and on it
    ey[::11] = ty
    final = heading + np.linspace(-3.0, 3.0, n)
    goals = LocalGoals.single((tx, ty))
    got = COMPILED.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), None, None, True)
    assert same_bits(got, NUMPY.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), None, None, True))


@st.composite
def choices(draw):
    """A window (paper's or with speeds; sum-normalised or fixed-scale; sloped sightline or not),
    random critics and legal sets, and the turn-around preference on or off."""
    speeds = draw(st.sampled_from([1, 1, 3, 5]))
    weights = [draw(st.sampled_from([0.0, 0.2, 0.37, 1.0])) for _ in range(4)]
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=0.35, samples=draw(st.sampled_from([1, 7, 31])), dt_s=0.5,
                       prediction_time_s=5.0, w_h=weights[0], w_d=weights[1], w_s=weights[2], w_v=weights[3],
                       sightline_cap_m=50.0, speed_samples=speeds, fixed_scale=draw(st.booleans()),
                       sightline_slope=draw(st.booleans()))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    n = config.count
    legal = rng.random(n) < draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))
    heading = rng.uniform(0.0, 180.0, n)
    heading[::3] = 180.0  # ties
    distance = config.saturated_m if draw(st.booleans()) else np.minimum(rng.uniform(-1.0, 12.0, n).clip(0.0), 10.0)
    sightline = draw(st.sampled_from([None, "zero", "random"]))
    if sightline is not None:
        sightline = np.zeros(n) if sightline == "zero" else rng.uniform(-50.0 if config.sightline_slope else 0.0,
                                                                        50.0, n)
    speed = None if config.count == config.samples else rng.uniform(0.0, 1.0, n)
    error = draw(st.sampled_from([float("nan"), 2.5, -2.0, 0.0]))
    return config, Critics(legal, error, distance, sightline, speed), heading


@needs_numba
@settings(max_examples=200, deadline=None)
@given(choices())
def test_choice_kernel_matches_numpy(case) -> None:
    """The compiled choice (turn preference, normalised weighted sum, argmax) picks the same
    rollout with the same total, to the last bit, and counts the same legal rollouts."""
    got, reference = COMPILED.choose(*case), NUMPY.choose(*case)
    assert got[0] == reference[0] and got[2] == reference[2]
    assert same_bits(np.array([got[1]]), np.array([reference[1]]))
