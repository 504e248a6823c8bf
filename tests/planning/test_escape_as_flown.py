"""The escape, judged on the true footprints, must be judged as the lagging plant flies it.

Seed 9091 scenario 12 with eight vehicles (astar-bdwa, multicopter): UAV e, flying toward its
local goal between a static square and a disc (true radius 142 m, margin 28 m) coming at it at
3.8 m/s, with vehicles about that have the right of way, found no legal rollout and escaped,
tick after tick, along the turn that stays clear of the disc's true footprint for the whole
horizon. That turn grazed the true footprint by 0.3-4 m; the multicopter's velocity trails its
heading by ~2 s, so it flew wide of every such turn, and after 24 escape ticks into the disc.
This is the fifth of those ticks (the flight itself is in tests/test_swarm.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.planning.dwa import (DwaConfig, LocalGoals, NoLegalRollout, ObstacleSnapshot, OtherUav, Pose,
                                    plan_step)
from companion.planning.dwa.geometry import inflated_clearance
from companion.planning.dwa.shapes import lagged_points, placement
from companion.planning.flight.loop import body_command
from uav_model.frames import enu_heading_to_ned_yaw, enu_to_ned, ned_to_enu
from uav_model.plant import TRACKING_LAG_S, KinematicState, Plant, initial_state, limits_for, step_for

# In the scenario's coordinates: e heading south-south-east, its velocity still trailing 22 deg
# to the right at 6.6 m/s; the disc coming north-west; the static square south of the local
# goal; the three vehicles nearby, each with the right of way.
SNAPSHOT = ObstacleSnapshot.build(
    [("m1", 1319.01, 1946.60, 142.15, 28.43, -2.816, 2.611)],
    [("s4", np.array([[908.9, 1498.6], [1240.6, 2032.1], [1774.1, 1700.4], [1442.4, 1166.9]]), 88.84, 0.0, 0.0)])
UAVS = (OtherUav(1056.86, 1964.70, 5.0, 8.42, right_of_way=True),
        OtherUav(976.62, 1896.06, 5.82, 7.90, right_of_way=True),
        OtherUav(1247.32, 2229.14, -6.58, -7.28, right_of_way=True))
POSE, VELOCITY_M_S = Pose(1173.72, 2107.48, -1.2159), (-0.25, -6.57)
GOALS = LocalGoals(np.array([(1145.0, 2085.0), (5.0, 115.0)]), (1535.0, 2295.0), 30.0, 20.0, ends_at_station=False)
CONFIG = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, samples=31, dt_s=0.5, prediction_time_s=11.0,
                   w_h=0.37, w_d=0.6, w_s=0.0, sightline_cap_m=100.0, min_separation_m=55.0,
                   tracking_lag_s=TRACKING_LAG_S[Plant.MULTICOPTER])


def true_clearance(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    margins = np.concatenate([SNAPSHOT.circle_margin_m, SNAPSHOT.poly_margin_m])
    return (inflated_clearance(x, y, t, SNAPSHOT) + margins[:, None]).min(axis=0)


def flown_clearance(yaw_rate_rad_s: float, speed_m_s: float) -> float:
    """The least true clearance of the multicopter holding that command over the horizon."""
    plant = Plant.MULTICOPTER
    limits = limits_for(plant, speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, max_accel_m_s2=3.0)
    vn, ve, _ = enu_to_ned(*VELOCITY_M_S)
    north, east, _ = enu_to_ned(POSE.x_m, POSE.y_m)
    state = initial_state(plant, KinematicState(north_m=north, east_m=east, down_m=-50.0, vn_m_s=vn, ve_m_s=ve,
                                                yaw_rad=enu_heading_to_ned_yaw(POSE.heading_rad)), limits)
    xy = []
    for _ in range(CONFIG.steps):
        state = step_for(plant)(state, body_command(yaw_rate_rad_s, speed_m_s), limits, CONFIG.dt_s)
        xy.append(ned_to_enu(state.north_m, state.east_m)[:2])
    x, y = np.array(xy).T
    return float(true_clearance(x, y, CONFIG.times_s[1:]).min())


def escape_rollout_clearance(yaw_rate_rad_s: float, speed_m_s: float) -> float:
    """The least true clearance along the window's rollout of that command."""
    i = int(np.flatnonzero(np.isclose(CONFIG.yaw_rates_rad_s, yaw_rate_rad_s)
                           & np.isclose(CONFIG.speeds_m_s, speed_m_s))[0])
    x, y = placement(POSE)[:, :2] @ CONFIG.body_xy_m[i].T + placement(POSE)[:, 2:]
    return float(true_clearance(x[1:], y[1:], CONFIG.times_s[1:]).min())


@pytest.mark.parametrize("speed_m_s", [10.0, 5.0, 0.0])
def test_the_lagged_rollouts_are_what_the_multicopter_flies_the_arcs_are_not(speed_m_s):
    """From cruise (a pose without its velocity is taken to be at cruise along its heading), from
    half of it and from rest: the plant's velocity lag is linear, so the rollouts flown from a
    velocity are those from rest plus that velocity carried on."""
    plant = Plant.MULTICOPTER
    limits = limits_for(plant, speed_m_s=10.0, max_yaw_rate_rad_s=1.0 / 3.0, max_accel_m_s2=3.0)
    pose = Pose(0.0, 0.0, 0.0) if speed_m_s == 10.0 else Pose(0.0, 0.0, 0.0, speed_m_s, 0.0)
    lagged = lagged_points(pose, CONFIG).T.reshape(CONFIG.body_xy_m.shape)
    off_arc, off_lagged = [], []
    for i in range(0, CONFIG.count, 5):
        vn, ve, _ = enu_to_ned(speed_m_s, 0.0)
        state = initial_state(plant, KinematicState(north_m=0.0, east_m=0.0, down_m=-50.0, vn_m_s=vn, ve_m_s=ve,
                                                    yaw_rad=enu_heading_to_ned_yaw(0.0)), limits)
        for k in range(1, CONFIG.steps + 1):
            state = step_for(plant)(state, body_command(CONFIG.yaw_rates_rad_s[i], 10.0), limits, CONFIG.dt_s)
            xy = np.array(ned_to_enu(state.north_m, state.east_m)[:2])
            off_arc.append(np.hypot(*(xy - CONFIG.body_xy_m[i, k])))
            off_lagged.append(np.hypot(*(xy - lagged[i, k])))
    assert max(off_lagged) < 5.0 < 20.0 < max(off_arc)
    assert lagged_points(pose, dataclasses.replace(CONFIG, tracking_lag_s=0.0)) is None  # the unicycle flies the arcs


def test_the_turn_that_grazes_the_true_footprint_is_flown_into_it_by_the_lagging_plant():
    # The window's hardest left turn here stays 17 m off the disc, the multicopter holding it
    # comes within 2 m; the next ones in (the escape chose the third) graze it and are flown into it.
    assert escape_rollout_clearance(1.0 / 3.0, 10.0) > 15.0 and flown_clearance(1.0 / 3.0, 10.0) < 5.0
    assert 0.0 < escape_rollout_clearance(CONFIG.yaw_rates_rad_s[27], 10.0) < 5.0
    assert flown_clearance(CONFIG.yaw_rates_rad_s[27], 10.0) < 0.0


def test_boxed_in_the_fallback_held_by_the_multicopter_stays_off_the_true_footprint():
    here = float(true_clearance(np.array([POSE.x_m]), np.array([POSE.y_m]), np.zeros(1))[0])
    assert here > 70.0
    found = plan_step(POSE, GOALS, None, SNAPSHOT, CONFIG, separate_from=UAVS)
    assert isinstance(found, NoLegalRollout)  # no rollout keeps every rule
    command = found.escape or found.recovery  # an escape, a yaw in place, or a hover
    assert flown_clearance(*((0.0, 0.0) if command is None else (command.yaw_rate_rad_s, command.speed_m_s))) > 0.0
