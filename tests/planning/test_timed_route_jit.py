"""The compiled queries of a timed route (:mod:`companion.planning.timed_route_jit`: the schedule
clocks' reach, one position's progress, a tick's whole schedule) give bit for bit the numpy and
plain-float queries' answers, over random
timed routes (waits, holds, times before and after the route, windows anywhere along it), and
both find the time a vehicle seen on the plan is at."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.planning import timed_route
from companion.planning.timed_route import TimedRoute
from companion.planning.timed_route_jit import latest_near, progress_in, schedule_in

needs_numba = pytest.mark.skipif(latest_near is None or progress_in is None or schedule_in is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")
OFFSETS = np.arange(0.0, 60.0 + 0.25, 0.5)  # a ScheduleClock's default window


@st.composite
def routes(draw) -> TimedRoute:
    """2-12 points up to 400 m apart, some repeated (a wait), at times 0-30 s apart."""
    n = draw(st.integers(2, 12))
    xy = [(draw(st.floats(-400.0, 400.0)), draw(st.floats(-400.0, 400.0)))]
    for _ in range(n - 1):
        xy.append(xy[-1] if draw(st.booleans()) and draw(st.booleans()) else
                  (draw(st.floats(-400.0, 400.0)), draw(st.floats(-400.0, 400.0))))
    gaps = draw(st.lists(st.one_of(st.just(0.0), st.floats(0.1, 30.0)), min_size=n - 1, max_size=n - 1))
    return TimedRoute("v", np.concatenate([[draw(st.floats(0.0, 50.0))], gaps]).cumsum(), np.array(xy))


def _numpy(route: TimedRoute, xy, t0: float, tol: float, monkeypatch) -> float:
    with monkeypatch.context() as m:
        m.setattr(timed_route, "latest_near", None)
        return route.latest_near_s(xy, t0, OFFSETS, tol)


@needs_numba
@settings(max_examples=300, deadline=None)
@given(routes(), st.floats(-20.0, 200.0), st.floats(-450.0, 450.0), st.floats(-450.0, 450.0),
       st.sampled_from([0.0, 1.0, 5.0]))
def test_compiled_query_gives_the_numpy_bits(route, t0, x, y, tol):
    mp = pytest.MonkeyPatch()
    try:
        expected = _numpy(route, (x, y), t0, tol, mp)
    finally:
        mp.undo()
    assert route.latest_near_s((x, y), t0, OFFSETS, tol) == expected


@pytest.mark.parametrize("compiled", [False, True])
def test_a_vehicle_on_its_plan_is_found_at_its_planned_time(compiled, monkeypatch):
    if compiled and latest_near is None:
        pytest.skip("needs the fast extra (numba)")
    if not compiled:
        monkeypatch.setattr(timed_route, "latest_near", None)
    route = TimedRoute("v", np.array([0.0, 10.0, 40.0, 50.0]), np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 0.0],
                                                                          [100.0, 100.0]]))
    assert route.latest_near_s((50.0, 0.0), 0.0, OFFSETS, 1.0) == 5.0  # halfway along the first leg
    # waiting at the corner from 10 s to 40 s: the latest time it is still there counts
    assert route.latest_near_s((100.0, 0.0), 0.0, OFFSETS, 1.0) == 40.0
    assert route.latest_near_s((100.0, 50.0), 20.0, OFFSETS, 1.0) == 45.0


@needs_numba
@settings(max_examples=300, deadline=None)
@given(routes(), st.floats(-450.0, 450.0), st.floats(-450.0, 450.0),
       st.one_of(st.none(), st.floats(-100.0, 3000.0)))
def test_compiled_progress_gives_the_numpy_bits(route, x, y, near):
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(timed_route, "progress_near", None)
        expected = route.progress_at(np.array([x, y]), near)
    finally:
        mp.undo()
    found = route.progress_at(np.array([x, y]), near)
    assert (float(found[0]), float(found[1])) == (float(expected[0]), float(expected[1]))


@settings(max_examples=300, deadline=None)
@given(routes(), st.lists(st.floats(-10.0, 400.0), min_size=1, max_size=8), st.data())
def test_one_time_interpolation_is_numpys(route: TimedRoute, times: list[float], data) -> None:
    """How far along the plan is at one time, the per-tick query, in plain floats: numpy's bits
    at any time, the route's own times (a wait's both ends) and its ends included."""
    times = times + [float(data.draw(st.sampled_from(route.t_s.tolist())))]
    for t in times:
        got = route.planned_along_at(t)
        reference = np.interp(np.asarray(t), route.t_s, route._along_m)
        assert type(got) is np.float64 and got.tobytes() == np.float64(reference).tobytes()


@settings(max_examples=300, deadline=None)
@given(routes(), st.floats(-450.0, 450.0), st.floats(-450.0, 450.0), st.floats(-10.0, 400.0),
       st.one_of(st.none(), st.floats(0.0, 900.0)), st.sampled_from([0.5, 5.0, 10.0, 30.0]))
def test_one_position_target_speed_is_the_vectorised_formula(route: TimedRoute, x: float, y: float, t: float,
                                                             near, max_speed: float) -> None:
    """The speed a tick asks for (one position, one time, plain floats) is the vectorised
    formula's on that position's progress, to the bit, and the array query's progress is its."""
    along, off = route.progress_of(x, y, near)
    got = route.target_speed_of(x, y, t, max_speed, near_along_m=near)
    gap = route.planned_along_at(np.asarray([t + 5.0])) - along
    reference = np.where(gap > 0, np.minimum(np.hypot(gap, off) / 5.0, max_speed), 0.0)[0]
    assert type(got) is np.float64 and got.tobytes() == reference.tobytes()
    assert route.progress_at(np.array([x, y]), near) == (along, off)


@needs_numba
@settings(max_examples=300, deadline=None)
@given(routes(), st.floats(-450.0, 450.0), st.floats(-450.0, 450.0), st.floats(-10.0, 400.0),
       st.one_of(st.none(), st.floats(-100.0, 3000.0)), st.sampled_from([0.5, 5.0, 10.0, 30.0]), st.data())
def test_compiled_schedule_gives_the_plain_float_bits(route: TimedRoute, x: float, y: float, t: float, near,
                                                      max_speed: float, data) -> None:
    """A tick's schedule in one compiled call (progress near where the vehicle was, the target
    speed from there, the lead, the wait) is the four queries' answers, to the bit: at any time,
    the route's own times (a wait's both ends) included."""
    if data.draw(st.booleans()):
        t = float(data.draw(st.sampled_from(route.t_s.tolist())))
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(timed_route, "schedule_in", None)
        expected = route.schedule_of(x, y, t, max_speed, near)
    finally:
        mp.undo()
    along = float(route.progress_of(x, y, near)[0])
    assert expected == (along, float(route.target_speed_of(x, y, t, max_speed, near_along_m=along)),
                        along - float(route.planned_along_at(t)), bool(route.is_waiting_at(t)))
    got = route.schedule_of(x, y, t, max_speed, near)
    assert [type(v) for v in got] == [float, float, float, bool]
    assert np.array(got[:3]).tobytes() == np.array(expected[:3]).tobytes() and got[3] == expected[3]


@needs_numba
@settings(max_examples=200, deadline=None)
@given(routes(), st.lists(st.tuples(st.floats(-450.0, 450.0), st.floats(-450.0, 450.0), st.floats(-20.0, 200.0)),
                          min_size=1, max_size=30), st.sampled_from([0.0, 5.0, 50.0]))
def test_the_first_lead_over_a_limit_is_the_compiled_and_the_tick_by_tick_one(route, track, limit):
    """A recorded flight checked against a pace in one compiled call finds the tick that
    :meth:`TimedRoute.schedule_of`, asked tick by tick, finds (or none)."""
    xs, ys, ts = (np.array(c) for c in zip(*track))
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(timed_route, "first_lead_over", None)
        mp.setattr(timed_route, "schedule_in", None)
        expected = route.first_lead_over(xs, ys, ts, limit)
    finally:
        mp.undo()
    assert route.first_lead_over(xs, ys, ts, limit) == expected


def test_a_vehicle_ahead_of_its_pace_is_found_at_the_first_tick_ahead():
    route = TimedRoute("v", np.array([0.0, 100.0]), np.array([[0.0, 0.0], [1000.0, 0.0]]))  # 10 m/s
    ts = np.arange(0.0, 10.0, 1.0)
    on = 10.0 * ts
    assert route.first_lead_over(on, np.zeros_like(ts), ts, 5.0) is None
    ahead = on + np.where(ts >= 6.0, 6.0, 0.0)
    assert route.first_lead_over(ahead, np.zeros_like(ts), ts, 5.0) == 6
