"""Obstacle shapes, inflation and motion models."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_model.world import Orbit, Patrol, Shuttle, Static, make_obstacle

coords = st.floats(-2000, 2000)
speeds = st.floats(0.5, 20)


def test_circle_inflates_by_twenty_percent_of_radius():
    o = make_obstacle("c", "circle", center=(707.11, 707.11), radius_m=500.0)
    assert o.inflated_radius_m == pytest.approx(600.0)
    assert o.inflated.area == pytest.approx(math.pi * 600.0**2, rel=1e-3)


@pytest.mark.parametrize(
    ("kind", "kwargs", "size"),
    [
        ("rectangle", {"center": (0, 0), "width_m": 300, "height_m": 400}, 250.0),
        ("triangle", {"center": (10, 20), "circumradius_m": 300}, 300.0),
        ("polygon", {"vertices": [(0, 0), (200, 0), (200, 200), (0, 200)]}, math.hypot(100, 100)),
    ],
)
def test_shape_size_is_circumradius_and_true_shape_is_inside_inflated(kind, kwargs, size):
    o = make_obstacle("o", kind, inflation_ratio=0.2, **kwargs)
    assert o.size_m == pytest.approx(size)
    assert o.inflated.contains(o.footprint)
    assert o.inflated.exterior.hausdorff_distance(o.footprint.exterior) == pytest.approx(0.2 * size, rel=0.02)


def test_equilateral_triangle_has_equal_sides():
    o = make_obstacle("t", "triangle", center=(0, 0), circumradius_m=100, rotation_deg=17)
    v = o.vertices()
    sides = np.hypot(*np.diff(np.vstack([v, v[:1]]), axis=0).T)
    assert sides == pytest.approx([100 * math.sqrt(3)] * 3)


def _finite_difference_matches_velocity(motion, t):
    h = 1e-3
    d = (motion.offset_at(t + h) - motion.offset_at(t - h)) / (2 * h)
    return np.allclose(d, motion.velocity_at(t), atol=1e-3)


@settings(max_examples=60)
@given(coords, coords, speeds, st.floats(0, 5000))
def test_shuttle_goes_there_and_back_at_speed(dx, dy, speed, t):
    m = Shuttle(delta_m=(dx, dy), speed_m_s=speed)
    length = math.hypot(dx, dy)
    if length < 1.0:
        return
    period = 2 * length / speed
    assert np.allclose(m.offset_at(period / 2), (dx, dy), atol=1e-6 * length + 1e-6)
    assert np.allclose(m.offset_at(period), (0, 0), atol=1e-6 * length + 1e-6)
    assert math.hypot(*m.velocity_at(t)) == pytest.approx(speed)
    if abs((t * speed) % length) > 1e-2 and abs((t * speed) % length - length) > 1e-2:
        assert _finite_difference_matches_velocity(m, t)


@settings(max_examples=60)
@given(coords, coords, st.floats(50, 2000), speeds, st.booleans(), st.floats(0, 5000))
def test_orbit_keeps_radius_and_speed(px, py, r, speed, cw, t):
    m = Orbit(pivot_m=(px, py), start_m=(px + r, py), speed_m_s=speed, clockwise=cw)
    pos = np.asarray((px + r, py)) + m.offset_at(t)
    assert math.hypot(pos[0] - px, pos[1] - py) == pytest.approx(r)
    assert math.hypot(*m.velocity_at(t)) == pytest.approx(speed)
    assert _finite_difference_matches_velocity(m, t)


def test_patrol_visits_waypoints_in_order_and_loops():
    m = Patrol(loop_m=((0.0, 0.0), (100.0, 0.0), (100.0, 100.0)), speed_m_s=10.0)
    assert np.allclose(m.offset_at(10.0), (100, 0))
    assert np.allclose(m.offset_at(20.0), (100, 100))
    total = 200 + math.hypot(100, 100)
    assert np.allclose(m.offset_at(total / 10.0), (0, 0), atol=1e-9)
    assert m.velocity_at(5.0) == pytest.approx((10.0, 0.0))
    assert m.offset_at(np.array([0.0, 10.0, 20.0])).shape == (3, 2)


@settings(max_examples=80)
@given(st.sampled_from(["static", "shuttle", "orbit", "patrol"]), coords, coords, st.floats(1.0, 900.0), speeds,
       st.booleans(), st.lists(st.tuples(coords, coords), min_size=2, max_size=6))
def test_offset_disc_holds_every_offset(kind, x, y, r, speed, cw, loop):
    """The disc a motion sweeps (Motion.offset_disc, what a contact check culls with) holds
    its offset at every time sampled over a few periods."""
    motion = {"static": Static(), "shuttle": Shuttle(delta_m=(x, y), speed_m_s=speed),
              "orbit": Orbit(pivot_m=(x, y), start_m=(x + r, y - r), speed_m_s=speed, clockwise=cw),
              "patrol": Patrol(loop_m=tuple(loop), speed_m_s=speed)}[kind]
    (cx, cy), radius = motion.offset_disc
    off = motion.offset_at(np.linspace(0.0, 4000.0, 4001))
    assert (np.hypot(off[:, 0] - cx, off[:, 1] - cy) <= radius + 1e-9 * (1.0 + radius)).all()
