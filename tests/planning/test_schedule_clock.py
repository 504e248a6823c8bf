"""The schedule's common clock (timed.ScheduleClock): held back by a vehicle that lags its plan,
not by one that sits in a planned wait, never back in time, never more than max_lag_s behind."""

from __future__ import annotations

import numpy as np
import pytest

from companion.planning.coordination.clocks import ScheduleClock
from companion.planning.coordination.timed import forecast

EAST = np.array([[0.0, 0.0], [1000.0, 0.0]])
NORTH = np.array([[0.0, 100.0], [0.0, 1100.0]])


def _clock(**kw) -> ScheduleClock:
    # a holds 30 s, then flies east at 10 m/s; b flies north at 10 m/s from t = 0.
    return ScheduleClock({"a": forecast("a", EAST, 10.0, hold_s=30.0), "b": forecast("b", NORTH, 10.0)}, **kw)


def test_on_plan_the_clock_is_sim_time_and_a_planned_wait_does_not_hold_it():
    clock = _clock()
    for t in np.arange(0.0, 60.0, 0.5):
        clock.observe("a", (max(0.0, 10.0 * (t - 30.0)), 0.0), t)  # waits at its start, then leaves on time
        clock.observe("b", (0.0, 100.0 + 10.0 * t), t)
        assert clock.now(t) == pytest.approx(t)
    assert clock.worst_lag_s == pytest.approx(0.0)


def test_a_vehicle_that_lost_time_holds_the_clock_back_and_the_others_with_it():
    clock = _clock()
    t = 0.0
    for t in np.arange(0.0, 20.0, 0.5):  # b hovered at its start for 20 s (e.g. telemetry gaps)
        clock.observe("a", (0.0, 0.0), t)
        clock.observe("b", (0.0, 100.0), t)
        tau = clock.now(t)
    assert tau == pytest.approx(2.0)  # b's reach (0 s) plus the slack, not 19.5 s
    assert clock.lag_s(t) == pytest.approx(t - 2.0)
    # b flies again: the clock follows its progress, and never runs backwards.
    clock.observe("b", (0.0, 150.0), 20.0)
    assert clock.now(20.0) == pytest.approx(7.0)
    clock.observe("b", (0.0, 100.0), 20.5)  # a stale or noisy sample behind its reach
    assert clock.now(20.5) == pytest.approx(7.0)


def test_an_arrived_vehicle_and_one_far_off_its_plan_stop_holding_it():
    clock = _clock(max_lag_s=10.0)
    for t in np.arange(0.0, 30.0, 0.5):
        clock.observe("a", (0.0, 0.0), t)
        clock.observe("b", (0.0, 100.0), t)
        tau = clock.now(t)
    assert tau == pytest.approx(29.5 - 10.0)  # at most max_lag_s behind
    clock.done("b")
    assert clock.now(30.0) == pytest.approx(30.0)  # a waits in its planned hold: nobody holds it back
