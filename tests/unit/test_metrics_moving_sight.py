"""Regression: the sight-line metric with a mix of fixed and moving circles."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from companion.planning.metrics import TruthGeometry
from companion.planning.world import Shuttle, World, make_obstacle


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
