"""Arrival is judged along each step's segment, with the time interpolated inside the step."""

from __future__ import annotations

import numpy as np
import pytest

from companion.planning.metrics import Track, arrival


def test_a_step_that_passes_through_the_disc_arrives_at_the_entry_time():
    # 40 m steps at 10 m/s: no sample lands within 20 m of the goal at x = 100, but step 2 enters it.
    track = Track(np.array([0.0, 4.0, 8.0, 12.0]), np.array([0.0, 40.0, 80.0, 120.0]), np.zeros(4))
    t, i, s = arrival(track, (100.0, 0.0), 20.0)
    assert i == 1 and s == pytest.approx(1.0)  # enters at x = 80: the end of step 1
    assert t == pytest.approx(8.0)
    t, i, s = arrival(track, (110.0, 5.0), 20.0)
    assert i == 2 and t == pytest.approx(8.0 + 4.0 * (110.0 - np.sqrt(20.0**2 - 5.0**2) - 80.0) / 40.0)


def test_passing_wide_of_the_disc_is_no_arrival():
    track = Track(np.array([0.0, 1.0]), np.array([0.0, 100.0]), np.array([0.0, 0.0]))
    assert arrival(track, (50.0, 25.0), 20.0)[0] is None
    assert arrival(track, (50.0, 19.0), 20.0)[0] == pytest.approx((50.0 - np.sqrt(20.0**2 - 19.0**2)) / 100.0)


def test_starting_inside_is_arrival_at_the_first_sample():
    track = Track(np.array([3.0, 4.0]), np.array([0.0, 100.0]), np.array([0.0, 0.0]))
    assert arrival(track, (5.0, 0.0), 20.0) == (3.0, 0, 0.0)
