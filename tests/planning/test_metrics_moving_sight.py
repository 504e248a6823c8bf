"""Regression: the sight-line metric with a mix of fixed and moving circles."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from companion.planning.metrics import TruthGeometry
from uav_model.world import Shuttle, World, make_obstacle


def test_sight_blocked_follows_moving_circles():
    fixed = make_obstacle("fixed", "circle", center=(0.0, 1000.0), radius_m=100.0)
    moving = replace(make_obstacle("moving", "circle", center=(0.0, 0.0), radius_m=50.0),
                     motion=Shuttle(delta_m=(1000.0, 0.0), speed_m_s=10.0))
    geo = TruthGeometry(World(-2000, -2000, 2000, 2000, 100.0, (fixed, moving)))
    # A north-south sight line at x = 0 crosses the moving disc at t = 0 but not at t = 50 s
    # (it has moved 500 m east); a line at y = 1000 is always blocked by the fixed disc.
    t = np.array([0.0, 50.0])
    assert geo.sight_blocked(np.zeros(2), np.full(2, -200.0), np.zeros(2), np.full(2, 200.0), t).tolist() == [True, False]
    assert geo.sight_blocked(np.full(2, -500.0), np.full(2, 1000.0), np.full(2, 500.0), np.full(2, 1000.0), t).all()


def test_segment_clearance_is_exact_with_the_bounding_disc_shortcut_and_capped_by_upto():
    """Polygons are skipped where their bounding disc shows they cannot be the nearest footprint;
    the result must equal the plain minimum of shapely distances to every footprint."""
    import shapely

    square = make_obstacle("sq", "rectangle", center=(300.0, 0.0), width_m=200.0, height_m=100.0, rotation_deg=20.0)
    tri = make_obstacle("tri", "triangle", center=(-400.0, 200.0), circumradius_m=150.0, rotation_deg=5.0)
    drifting = replace(make_obstacle("drift", "rectangle", center=(0.0, -500.0), width_m=120.0, height_m=80.0),
                       motion=Shuttle(delta_m=(0.0, 600.0), speed_m_s=5.0))
    disc = make_obstacle("disc", "circle", center=(0.0, 400.0), radius_m=80.0)
    obstacles = (square, tri, drifting, disc)
    geo = TruthGeometry(World(-2000, -2000, 2000, 2000, 100.0, obstacles))
    rng = np.random.default_rng(5)
    x0, y0 = rng.uniform(-900, 900, 400), rng.uniform(-900, 900, 400)
    x1, y1 = x0 + rng.uniform(-60, 60, 400), y0 + rng.uniform(-60, 60, 400)
    t0 = rng.uniform(0, 200, 400)
    t1 = t0 + 0.5
    got = geo.segment_clearance_m(x0, y0, x1, y1, t0, t1)
    seg = shapely.linestrings(np.stack([np.stack([x0, y0], -1), np.stack([x1, y1], -1)], axis=-2))
    want = shapely.distance(seg, shapely.Point(disc.center)) - 80.0  # the disc is exact, not its polygon
    for o in (square, tri, drifting):
        o0, o1 = o.offset_at(t0), o.offset_at(t1)  # exact for the moving one: measured in its frame
        lines = shapely.linestrings(np.stack([np.stack([x0 - o0[:, 0], y0 - o0[:, 1]], -1),
                                              np.stack([x1 - o1[:, 0], y1 - o1[:, 1]], -1)], axis=-2))
        want = np.minimum(want, shapely.distance(lines, o.footprint))
    assert np.allclose(got, np.maximum(want, 0.0), atol=1e-6)
    assert (got <= 0.0).any() and (got > 100.0).any()  # both contacts and open air were sampled
    capped = geo.segment_clearance_m(x0, y0, x1, y1, t0, t1, upto_m=1.0)
    assert np.array_equal(capped <= 0.0, got <= 0.0)
    assert np.allclose(capped, np.minimum(got, 1.0), atol=1e-6)
