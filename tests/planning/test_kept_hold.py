"""The first vehicle's departure hold kept against the lower vehicles (coordination.clocks.KeptHold): it departs
as much later as they lag their plans, at most what hold_s_max leaves,
and from then on reads sim time less that extra hold."""

from __future__ import annotations

import numpy as np
import pytest

from companion.planning.coordination.clocks import KeptHold
from companion.planning.coordination.timed import forecast

A = forecast("a", np.array([[0.0, 0.0], [1000.0, 0.0]]), 10.0, hold_s=30.0)  # departs at t = 30 s
B = forecast("b", np.array([[0.0, 500.0], [1000.0, 500.0]]), 10.0)           # cruises from t = 0


def _departure(kept: KeptHold, b_lag_m: float) -> float:
    """Tick both each 0.5 s, b flying its plan ``b_lag_m`` behind; the sim time a's clock reaches 30 s."""
    for t in np.arange(0.0, 120.0, 0.5):
        kept.observe("b", (max(0.0, 10.0 * t - b_lag_m), 500.0), t)
        if kept.now(t) >= A.departure_s:
            return float(t)
    raise AssertionError("a never departed")


def test_on_plan_below_the_first_departs_at_its_planned_hold():
    kept = KeptHold(A, {"b": B}, extra_max_s=10.0)
    assert _departure(kept, 0.0) == pytest.approx(30.0)
    assert kept.extra_s == pytest.approx(0.0)
    assert kept.now(50.0) == pytest.approx(50.0)


def test_a_lagging_vehicle_below_holds_the_first_back_then_its_clock_keeps_the_offset():
    kept = KeptHold(A, {"b": B}, extra_max_s=10.0)
    t = _departure(kept, 60.0)  # b 6 s behind its plan
    assert t == pytest.approx(36.0, abs=0.51) and kept.extra_s == pytest.approx(t - 30.0, abs=0.51)
    assert kept.now(80.0) == pytest.approx(80.0 - kept.extra_s)  # in flight a waits for nobody


def test_the_extra_hold_stops_at_what_hold_s_max_leaves():
    kept = KeptHold(A, {"b": B}, extra_max_s=3.0)
    assert _departure(kept, 300.0) == pytest.approx(33.0, abs=0.51)
    assert kept.extra_s == pytest.approx(3.0, abs=0.51)


def test_a_vehicle_below_that_is_done_holds_nobody_and_no_hold_keeps_sim_time():
    kept = KeptHold(A, {"b": B}, extra_max_s=10.0)
    kept.done("b")
    assert _departure(kept, 300.0) == pytest.approx(30.0)
    unheld = KeptHold(B, {"a": A}, extra_max_s=10.0)  # a route without a hold
    assert [unheld.now(t) for t in (0.0, 5.0, 50.0)] == [0.0, 5.0, 50.0]
