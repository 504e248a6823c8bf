"""Regression: the sight-line metric with a mix of fixed and moving circles; the clearance
shortcuts (bounding discs, swept discs) change no value."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.planning.metrics import TruthGeometry
from uav_model.world import Orbit, Patrol, Shuttle, World, make_obstacle


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


def _world(draw_obstacles) -> World:
    return World(-3000, -3000, 3000, 3000, 100.0, tuple(draw_obstacles))


@st.composite
def contact_cases(draw):
    """Circles and polygons, fixed, shuttling, orbiting or patrolling, and short segments
    (a batch of flown steps) anywhere among them, some grazing or crossing a footprint."""
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    obstacles = []
    for i in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["circle", "rectangle", "triangle"]))
        centre = tuple(rng.uniform(-1500.0, 1500.0, 2))
        size = float(rng.uniform(20.0, 300.0))
        shape = {"circle": dict(radius_m=size), "rectangle": dict(width_m=size, height_m=0.6 * size),
                 "triangle": dict(circumradius_m=size)}[kind]
        motion = draw(st.sampled_from([None, "shuttle", "orbit", "patrol"]))
        motion = {None: None, "shuttle": Shuttle(delta_m=tuple(rng.uniform(-800.0, 800.0, 2)), speed_m_s=8.0),
                  "orbit": Orbit(pivot_m=(centre[0] + 200.0, centre[1]), start_m=centre, speed_m_s=6.0),
                  "patrol": Patrol(loop_m=(centre, (centre[0] + 300.0, centre[1]), (centre[0], centre[1] + 250.0)),
                                   speed_m_s=7.0)}[motion]
        obstacles.append(make_obstacle(f"o{i}", kind, center=centre, motion=motion, **shape))
    n = draw(st.integers(1, 80))
    x0, y0 = rng.uniform(-1800.0, 1800.0, (2, n))
    x1, y1 = x0 + rng.uniform(-20.0, 20.0, n), y0 + rng.uniform(-20.0, 20.0, n)
    t0 = draw(st.floats(0.0, 2000.0)) + 0.5 * np.arange(n)
    return _world(obstacles), (x0, y0, x1, y1, t0, t0 + 0.5)


@settings(max_examples=80, deadline=None)
@given(contact_cases(), st.sampled_from([0.0, 1.0, 30.0]))
def test_contact_check_culls_by_swept_discs_without_changing_a_clearance(case, upto):
    """A clearance capped at ``upto`` (the runner's safety batches) skips the obstacles whose
    swept disc no segment comes near: every value is the one without that culling, to the bit."""
    world, segments = case
    geo = TruthGeometry(world)
    got = geo.segment_clearance_m(*segments, upto_m=upto)
    geo._near_sweeps = lambda *args: np.ones(len(geo._sweep_r), dtype=bool)  # no culling
    reference = geo.segment_clearance_m(*segments, upto_m=upto)
    assert np.array_equal(got.view(np.uint64), reference.view(np.uint64))
