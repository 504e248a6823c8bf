"""The multicopter's substeps compiled (numba, the ``fast`` extra) fly bit for bit what the
Python loop flies, over random states, commands and step lengths."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_model.plant import multicopter
from uav_model.plant.state import KinematicState, VelocityCommand, VelocityFrame

pytestmark = pytest.mark.skipif(multicopter.numba is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")

value = st.floats(-30.0, 30.0, allow_nan=False)
states = st.builds(KinematicState, st.floats(-2000.0, 2000.0), st.floats(-2000.0, 2000.0), st.floats(-600.0, 10.0),
                   value, value, st.floats(-5.0, 5.0), st.floats(-3.2, 3.2), st.floats(-4.0, 4.0), value, value,
                   value, value)
commands = st.builds(VelocityCommand, st.sampled_from(list(VelocityFrame)), value, value, st.floats(-5.0, 5.0),
                     st.floats(-4.0, 4.0))


def bits(state: KinematicState) -> tuple[bytes, ...]:
    """Every field to the last bit, the sign of zero included."""
    return tuple(struct.pack("<d", v) for v in (state.north_m, state.east_m, state.down_m, state.vn_m_s,
                                                state.ve_m_s, state.vd_m_s, state.yaw_rad, state.yawspeed_rad_s,
                                                state.accel_n_m_s2, state.accel_e_m_s2, state.vel_int_n_m_s2,
                                                state.vel_int_e_m_s2))


@settings(max_examples=150, deadline=None)
@given(states, commands, st.sampled_from([0.02, 0.1, 0.25, 0.5, 1.3]))
def test_compiled_substeps_fly_what_the_python_loop_flies(state, command, dt_s):
    limits = multicopter.MulticopterLimits()
    compiled = multicopter.step(state, command, limits, dt_s)
    saved, multicopter._substep_loop = multicopter._substep_loop, multicopter.substep_loop_python
    try:
        reference = multicopter.step(state, command, limits, dt_s)
    finally:
        multicopter._substep_loop = saved
    assert bits(compiled) == bits(reference)


def test_integer_states_fly_as_floats():
    """A state written with integers (tests do) gives what the Python loop gives."""
    command = VelocityCommand(VelocityFrame.BODY_NED, 10.0, 0.0, 0.0, 0.2)
    state = KinematicState(0, 0, -50, 5, 0)
    compiled = multicopter.step(state, command, multicopter.MulticopterLimits(), 0.5)
    saved, multicopter._substep_loop = multicopter._substep_loop, multicopter.substep_loop_python
    try:
        reference = multicopter.step(state, command, multicopter.MulticopterLimits(), 0.5)
    finally:
        multicopter._substep_loop = saved
    assert bits(compiled) == bits(reference)
