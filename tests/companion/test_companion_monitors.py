"""The runner's safety monitors: pure look-ahead checks behind the planner."""

from __future__ import annotations

import math

import pytest

from companion.app import monitors
from companion.app.monitors import Kinematic2D
from uav_model.world import World


def _world() -> World:
    return World(0.0, 0.0, 1000.0, 1000.0, 100.0, ())


def test_unicycle_points_match_a_straight_line_and_a_circle():
    start = Kinematic2D(0.0, 0.0, 0.0)
    line = monitors.unicycle_points(start, 10.0, 0.0, 2.0, 0.5)
    assert line.shape == (4, 2)
    assert line[-1] == pytest.approx([20.0, 0.0])
    # A full turn at v/r stays on the turn circle (radius 30 m, centre (0, 30)).
    turn = monitors.unicycle_points(start, 10.0, 1.0 / 3.0, 2.0 * math.pi * 3.0, 0.01)
    r = [math.hypot(x, y - 30.0) for x, y in turn]
    assert min(r) == pytest.approx(30.0, abs=0.2) and max(r) == pytest.approx(30.0, abs=0.2)


def test_head_on_lower_priority_yields_and_priority_keeps_flying():
    a = Kinematic2D(0.0, 0.0, 0.0, 10.0, 0.0)
    b = Kinematic2D(80.0, 0.0, math.pi, -10.0, 0.0)  # closing at 20 m/s, 80 m apart
    kw = dict(min_separation_m=50.0, horizon_s=2.0, step_s=0.25)
    assert monitors.check_separation(b, 10.0, 0.0, a, own_has_priority=False, **kw).hover
    # a alone would only close to 60 m of where b is now: it keeps its command.
    assert not monitors.check_separation(a, 10.0, 0.0, b, own_has_priority=True, **kw).hover


def test_priority_vehicle_stops_short_of_a_hovering_vehicle():
    a = Kinematic2D(0.0, 0.0, 0.0, 10.0, 0.0)
    b = Kinematic2D(60.0, 0.0, math.pi, 0.0, 0.0)  # hovering 60 m ahead
    verdict = monitors.check_separation(a, 10.0, 0.0, b, own_has_priority=True,
                                        min_separation_m=50.0, horizon_s=2.0, step_s=0.25)
    assert verdict == monitors.Verdict(True, "separation")


def test_priority_vehicle_counts_its_stop_against_a_hovering_vehicle():
    # a closes to 60 m of the hovering b within the look-ahead: enough on an instant link, not
    # when a still flies 16 m on a late telemetry sample and its braking.
    a = Kinematic2D(0.0, 0.0, 0.0, 10.0, 0.0)
    b = Kinematic2D(80.0, 0.0, math.pi, 0.0, 0.0)
    kw = dict(own_has_priority=True, min_separation_m=50.0, horizon_s=2.0, step_s=0.25)
    assert not monitors.check_separation(a, 10.0, 0.0, b, **kw).hover
    assert monitors.check_separation(a, 10.0, 0.0, b, stop_m=monitors.stop_distance_m(10.0, 8.0, 1.0), **kw).hover


def test_diverging_vehicles_are_left_alone():
    a = Kinematic2D(0.0, 0.0, math.pi, -10.0, 0.0)
    b = Kinematic2D(70.0, 0.0, 0.0, 10.0, 0.0)
    for priority in (True, False):
        assert monitors.check_separation(a, 10.0, 0.0, b, own_has_priority=priority, min_separation_m=50.0,
                                         horizon_s=3.0, step_s=0.25) is monitors.FLY
    assert monitors.check_separation(a, 10.0, 0.0, None, own_has_priority=False, min_separation_m=50.0,
                                     horizon_s=3.0, step_s=0.25) is monitors.FLY


def test_geofence_exit_is_predicted_and_turning_away_is_not():
    w = _world()  # fence at x = 1100
    edge = Kinematic2D(1090.0, 500.0, 0.0)
    assert monitors.check_geofence(w, edge, 10.0, 0.0, horizon_s=2.0, step_s=0.25) == monitors.Verdict(True, "geofence")
    inward = Kinematic2D(1090.0, 500.0, math.pi)
    assert not monitors.check_geofence(w, inward, 10.0, 0.0, horizon_s=2.0, step_s=0.25).hover


def test_geofence_veto_comes_early_by_what_the_vehicle_flies_after_it():
    w = _world()  # fence at x = 1100
    # 30 m inside, flying at it: a 2 s arc ends 10 m inside, clear of the fence ...
    edge = Kinematic2D(1070.0, 500.0, 0.0)
    assert not monitors.check_geofence(w, edge, 10.0, 0.0, horizon_s=2.0, step_s=0.25).hover
    # ... not once a second of latency and the braking (10 m + 6.25 m at 8 m/s^2) are counted.
    stop = monitors.stop_distance_m(10.0, 8.0, 1.0)
    assert stop == pytest.approx(16.25)
    assert monitors.check_geofence(w, edge, 10.0, 0.0, horizon_s=2.0, step_s=0.25, stop_m=stop).hover
    inward = Kinematic2D(1070.0, 500.0, math.pi)
    assert not monitors.check_geofence(w, inward, 10.0, 0.0, horizon_s=2.0, step_s=0.25, stop_m=stop).hover


def test_a_vehicle_outside_the_geofence_may_fly_back_but_not_further_out():
    w = _world()  # fence at x = 1100 (area and margin)
    outside = Kinematic2D(1106.0, 500.0, math.pi)  # 6 m out, facing in: every arc starts outside
    assert monitors.check_geofence(w, outside, 10.0, 0.0, horizon_s=2.0, step_s=0.25) is monitors.FLY
    assert monitors.check_geofence(w, outside, 0.0, 0.5, horizon_s=2.0, step_s=0.25) is monitors.FLY
    along = Kinematic2D(1106.0, 500.0, math.pi / 2)  # along the fence, outside: no further out, allowed
    assert monitors.check_geofence(w, along, 10.0, 0.0, horizon_s=2.0, step_s=0.25) is monitors.FLY
    away = Kinematic2D(1106.0, 500.0, 0.3)
    assert monitors.check_geofence(w, away, 10.0, 0.0, horizon_s=2.0, step_s=0.25).hover
    # Inside the fence but within the stopping distance of it: the same rule, inward arcs fly.
    band = Kinematic2D(1090.0, 500.0, math.pi)
    assert monitors.check_geofence(w, band, 10.0, 0.0, horizon_s=2.0, step_s=0.25, stop_m=16.25) is monitors.FLY
    assert monitors.check_geofence(w, Kinematic2D(1090.0, 500.0, 0.0), 10.0, 0.0, horizon_s=2.0, step_s=0.25,
                                   stop_m=16.25).hover


def test_staleness_is_measured_on_the_vehicle_clock():
    assert not monitors.is_stale(10.0, None, 1.0)
    assert not monitors.is_stale(10.0, 10.9, 1.0)
    assert monitors.is_stale(10.0, 11.2, 1.0)


@pytest.mark.parametrize("rate, expected", [(None, 5.0), (1.0, 1.0), (20.0, 0.1), (5.0, 0.2), (0.1, 5.0)])
def test_wall_bound_scales_with_the_measured_speed_factor(rate, expected):
    assert monitors.wall_bound_s(1.0, rate) == pytest.approx(expected)


def test_vehicles_already_too_close_may_open_the_gap_but_not_close_it():
    # 45 m apart after a failsafe (limit 50 m), both hovering: every command was vetoed, for ever.
    a = Kinematic2D(0.0, 0.0, math.pi)  # facing away from b
    b = Kinematic2D(45.0, 0.0, math.pi)  # facing a
    kw = dict(min_separation_m=50.0, horizon_s=2.0, step_s=0.25)
    for priority in (True, False):
        assert monitors.check_separation(a, 5.0, 0.0, b, own_has_priority=priority, **kw) is monitors.FLY  # away
        assert monitors.check_separation(b, 5.0, 0.0, a, own_has_priority=priority, **kw).hover  # closer
