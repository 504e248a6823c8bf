"""The one unicycle integration (uav_model.plant.unicycle.body_rollouts) is what the plant flies."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_model.frames import enu_heading_to_ned_yaw, enu_yaw_rate_to_ned
from uav_model.plant import KinematicState, VehicleLimits, VelocityCommand, VelocityFrame, step
from uav_model.plant.unicycle import body_rollouts


@settings(max_examples=40, deadline=None)
@given(speed=st.floats(0.0, 15.0), rate=st.floats(-0.5, 0.5), heading=st.floats(-math.pi, math.pi))
def test_body_rollouts_are_what_the_plant_flies_from_that_speed(speed, rate, heading):
    dt, steps = 0.5, 12
    body, dheading = body_rollouts(np.array([speed]), np.array([rate]), dt, steps)
    c, s = math.cos(heading), math.sin(heading)
    state = KinematicState(north_m=0.0, east_m=0.0, down_m=-50.0, vn_m_s=speed * s, ve_m_s=speed * c,
                           yaw_rad=enu_heading_to_ned_yaw(heading))
    limits = VehicleLimits(15.0, 0.5, 8.0)
    command = VelocityCommand(VelocityFrame.BODY_NED, speed, 0.0, 0.0, enu_yaw_rate_to_ned(rate))
    for k in range(1, steps + 1):
        state = step(state, command, limits, dt)
        bx, by = body[0, k]
        assert (state.east_m, state.north_m) == pytest.approx((c * bx - s * by, s * bx + c * by), abs=1e-6)
    assert dheading[0, -1] == pytest.approx(rate * dt * steps)


def test_one_speed_for_all_equals_the_same_speed_per_rollout():
    rates = np.linspace(-0.3, 0.3, 7)
    a, _ = body_rollouts(10.0, rates, 0.5, 22)
    b, _ = body_rollouts(np.full(7, 10.0), rates, 0.5, 22)
    assert np.array_equal(a, b)
