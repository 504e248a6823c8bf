"""The circling measure of the scenario tests (companion.testing.approach), on made-up tracks."""

from __future__ import annotations

import numpy as np

from companion.planning.metrics import Track
from companion.testing.approach import station_approach

GOAL = (500.0, 500.0)


def _track(x, y, dt=0.5) -> Track:
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return Track(dt * np.arange(len(x)), x, y)


def test_a_straight_approach_is_not_circling():
    s = np.linspace(0.0, 1.0, 400)
    a = station_approach(_track(GOAL[0] - 300 * (1 - s), GOAL[1] - 300 * (1 - s)), GOAL, 80.0, 20.0)
    assert a.entered and a.arrived and not a.circling
    assert a.turned_deg < 1.0 and 59.0 < a.path_m < 62.0


def test_an_orbit_outside_the_arrival_radius_is_circling():
    # PX4's failure: in at 35 m from the station, round it three times, never within 20 m.
    lead = np.linspace(-300.0, -35.0, 60)
    ang = np.linspace(-np.pi, 5 * np.pi, 600)
    x = np.concatenate([GOAL[0] + lead, GOAL[0] + 35.0 * np.cos(ang)])
    y = np.concatenate([np.full(60, GOAL[1]), GOAL[1] + 35.0 * np.sin(ang)])
    a = station_approach(_track(x, y), GOAL, 80.0, 20.0)
    assert a.entered and not a.arrived and a.circling
    assert a.turned_deg > 3 * 360 - 20


def test_one_loop_inside_the_region_is_circling_and_hover_noise_is_not():
    rng = np.random.default_rng(3)
    hover = np.array(GOAL) + np.array([60.0, 0.0]) + rng.normal(0.0, 0.2, (200, 2))  # jitter 60 m out
    tail = np.linspace(60.0, 0.0, 30)
    x = np.concatenate([GOAL[0] + np.linspace(300.0, 60.0, 50), hover[:, 0], GOAL[0] + tail])
    y = np.concatenate([np.full(50, GOAL[1]), hover[:, 1], np.full(30, GOAL[1])])
    assert not station_approach(_track(x, y), GOAL, 80.0, 20.0).circling
    ang = np.linspace(0.0, 2 * np.pi, 200)
    loop_x = GOAL[0] + 50.0 + 15.0 * np.sin(ang)
    loop_y = GOAL[1] - 15.0 + 15.0 * np.cos(ang)
    x = np.concatenate([GOAL[0] + np.linspace(300.0, 50.0, 50), loop_x, GOAL[0] + np.linspace(50.0, 0.0, 30)])
    y = np.concatenate([np.full(50, GOAL[1]), loop_y, np.full(30, GOAL[1])])
    a = station_approach(_track(x, y), GOAL, 80.0, 20.0)
    assert a.arrived and a.circling and a.turned_deg > 340
