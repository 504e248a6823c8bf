"""A moving disc turns into a multicopter's path: the recovery must model the plant's lag.

Seed 7 scenario 15 (astar-bdwa-nosparse, the tuning seed): UAV b flew west at cruise under a
shuttling disc (true radius 98.75 m, margin 19.75 m) when the disc reversed and came down at
4.84 m/s. Every rollout broke the obstacle rule; the spin recovery then stopped b to yaw
105 deg in place, on the assumption that it hovers where it is and flies off at cruise after
the yaw. The multicopter braked over ~18 m along its heading into the disc's path, yawed with
its lag, re-chose its heading every tick, and was hit. This is that encounter, in closed loop
with the multicopter plant.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.planning.dwa import DwaConfig, NoLegalRollout, ObstacleSnapshot, OtherUav, Pose, plan_step
from companion.planning.dwa.recovery import hover_check
from companion.planning.flight.loop import body_command
from uav_model.frames import enu_heading_to_ned_yaw, enu_to_ned, ned_to_enu, ned_yaw_to_enu_heading
from uav_model.plant import HOVER, TRACKING_LAG_S, KinematicState, Plant, initial_state, limits_for, step_for

# Relative to the vehicle at the reversal, as in seed 7 i015 (its static polygon left out):
# the shuttling disc above, turned toward the vehicle; a second disc behind it, over the local
# goal, drifting toward its path; the vehicle flying away from that goal at cruise.
DISCS = (("m0", (-54.8, 113.7), 98.75, (-2.59, -4.09)), ("m1", (62.7, -174.3), 138.01, (-2.64, 1.80)))
HEADING_RAD, GOAL_XY_M = -2.993, (53.0, -176.7)


def fly(lag_s: float, seconds: float = 30.0) -> tuple[float, list[str]]:
    """Closed loop from the reversal: (the least distance to the disc's true footprint, what the
    planner did each tick that no rollout was legal)."""
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, samples=31, dt_s=0.5, prediction_time_s=11.0,
                       w_h=0.37, w_d=0.6, w_s=0.0, sightline_cap_m=100.0, tracking_lag_s=lag_s)
    plant = Plant.MULTICOPTER
    limits = limits_for(plant, speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, max_accel_m_s2=3.0)
    vn, ve, _ = enu_to_ned(10.0 * math.cos(HEADING_RAD), 10.0 * math.sin(HEADING_RAD))
    state = initial_state(plant, KinematicState(north_m=0.0, east_m=0.0, down_m=-50.0, vn_m_s=vn, ve_m_s=ve,
                                                yaw_rad=enu_heading_to_ned_yaw(HEADING_RAD)), limits)
    least, fallbacks = math.inf, []
    for k in range(int(seconds / config.dt_s)):
        t = k * config.dt_s
        x, y, _ = ned_to_enu(state.north_m, state.east_m)
        circles = [(name, cx + vx * t, cy + vy * t, r, 0.2 * r, vx, vy) for name, (cx, cy), r, (vx, vy) in DISCS]
        least = min(least, *(math.hypot(x - c[1], y - c[2]) - c[3] for c in circles))
        pose = Pose(x, y, ned_yaw_to_enu_heading(state.yaw_rad))
        result = plan_step(pose, GOAL_XY_M, None, ObstacleSnapshot.build(circles, []), config)
        if isinstance(result, NoLegalRollout):
            fallbacks.append("escape" if result.escape else "recovery" if result.recovery else "hold")
            result = result.escape or result.recovery
        command = HOVER if result is None else body_command(result.yaw_rate_rad_s, result.speed_m_s)
        state = step_for(plant)(state, command, limits, config.dt_s)
    return least, fallbacks


def test_a_disc_turning_into_the_path_is_outflown_not_waited_for():
    least, fallbacks = fly(TRACKING_LAG_S[Plant.MULTICOPTER])
    assert fallbacks and fallbacks[0] == "escape"  # no rollout is legal at the reversal: fly on
    assert "recovery" not in fallbacks
    assert least > 0.0  # never touches the true footprint


def test_the_same_encounter_without_the_lag_model_stops_in_the_path_and_is_hit():
    # What the planner did before (a plant that flies the rollouts exactly): spin in place.
    least, fallbacks = fly(0.0)
    assert fallbacks[0] == "recovery"
    assert least < 0.0


def test_hover_is_judged_on_the_braking_segment():
    # A static disc 10 m beyond the hover point's reach along the heading: the pose is clear,
    # the point the multicopter stops at (20 m ahead) is not.
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, samples=31, dt_s=0.5, prediction_time_s=11.0,
                       w_h=0.37, w_d=0.6, w_s=0.0, sightline_cap_m=100.0, tracking_lag_s=2.0)
    snap = ObstacleSnapshot.build([("d", 130.0, 0.0, 100.0, 20.0, 0.0, 0.0)], [])
    assert config.stop_drift_m == pytest.approx(20.0)
    assert not hover_check(Pose(0.0, 0.0, 0.0), (), snap, config).inflated[-1]  # stops 10 m inside it
    assert hover_check(Pose(0.0, 0.0, math.pi), (), snap, config).inflated[-1]  # braking away from it
    still = hover_check(Pose(0.0, 0.0, 0.0), (), snap, dataclasses.replace(config, tracking_lag_s=0.0))
    assert still.inflated[-1] and np.all(still.true)


HOVER_CONFIG = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, samples=31, dt_s=0.5, prediction_time_s=11.0,
                         w_h=0.37, w_d=0.6, w_s=0.0, sightline_cap_m=100.0, min_separation_m=55.0,
                         tracking_lag_s=2.0)
NOTHING = ObstacleSnapshot.build([], [])


def test_the_braking_segment_is_the_own_velocity_carried_on_and_binds_the_separation_too():
    """Seed 9192 scenario 6 with 16 vehicles: o and p stood 53 m apart, facing each other, and
    held for ever, each planner taking itself to be at cruise and so to stop 20 m nearer the
    other; and a vehicle at cruise that hovers 56 m short of another ends 36 m from it."""
    other = (OtherUav(53.0, 0.0, 0.0, 0.0),)
    at_rest = hover_check(Pose(0.0, 0.0, 0.0, 0.0, 0.0), other, NOTHING, HOVER_CONFIG)
    assert at_rest.inflated[-1] and at_rest.true[-1]
    cruising = hover_check(Pose(0.0, 0.0, 0.0), other, NOTHING, HOVER_CONFIG)  # no velocity: cruise along the heading
    assert not cruising.true[1]
    sideways = hover_check(Pose(0.0, 0.0, 0.0, 0.0, 10.0), other, NOTHING, HOVER_CONFIG)  # the velocity, not the nose
    assert sideways.true[-1]


def test_on_the_true_footprints_the_hover_may_use_the_right_of_ways_margin_not_the_separation():
    """A vehicle with right of way is kept 15 m farther (70 m here) than the separation (55 m);
    only the hover on the inflated footprints keeps that margin."""
    coming = (OtherUav(65.0, 0.0, -1.0, 0.0, right_of_way=True),)  # 10 s from 55 m
    hover = hover_check(Pose(0.0, 0.0, 0.0, 0.0, 0.0), coming, NOTHING, HOVER_CONFIG)
    assert not hover.inflated[1]
    assert hover.true[int(9.5 / HOVER_CONFIG.dt_s)] and not hover.true[int(10.5 / HOVER_CONFIG.dt_s)]
