"""The speed critic V: with a speed window, how close a rollout's speed is to the speed the
vehicle should fly now, so that a vehicle with nothing to wait for keeps cruise speed.

    V = 1 - |v - v_ref| / v_cruise   (in [0, 1])

v_ref is cruise speed, unless
- a timed route schedules less (the caller passes it: slow down or wait where the plan says), or
- the station is within reach but inside the turning circle a max-rate turn at cruise speed
  flies: then v_ref is the speed whose max-rate turn passes through the station, so the vehicle
  slows down and arrives instead of circling it (as a PX4 multicopter otherwise does, for as
  long as the mission lasts).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.types import LocalGoals, Pose

if TYPE_CHECKING:  # the config builds its cruise row with scores_at
    from companion.planning.dwa.config import DwaConfig


def station_speed_m_s(pose: Pose, goals: LocalGoals, config: DwaConfig) -> float:
    """The fastest speed whose max-rate turn still reaches the station (cruise when the station
    is not in the window or not inside a turning circle)."""
    if not goals.ends_at_station:
        return config.speed_m_s
    sx, sy = goals.nodes_xy[-1]
    dx, dy = float(sx) - pose.x_m, float(sy) - pose.y_m
    d2 = dx * dx + dy * dy
    if d2 > (config.reach_m + goals.station_radius_m) ** 2:
        return config.speed_m_s
    lateral = abs(-math.sin(pose.heading_rad) * dx + math.cos(pose.heading_rad) * dy)
    if lateral < 1e-9:
        return config.speed_m_s
    # The station at body (b_x, b_y) lies on the circle of radius R tangent to the heading when
    # R = |b|^2 / (2 |b_y|); a turn at rate w_max with speed v has radius v / w_max.
    return min(config.speed_m_s, config.max_yaw_rate_rad_s * d2 / (2.0 * lateral))


def reference_speed_m_s(pose: Pose, goals: LocalGoals, config: DwaConfig, scheduled_m_s: float | None) -> float:
    v_ref = config.speed_m_s if scheduled_m_s is None else min(max(scheduled_m_s, 0.0), config.speed_m_s)
    return min(v_ref, station_speed_m_s(pose, goals, config))


def speed_scores(config: DwaConfig, v_ref_m_s: float) -> np.ndarray:
    """V (S,) for every rollout; toward cruise speed (most ticks) the config's row, made once."""
    if v_ref_m_s == config.speed_m_s:
        return config.cruise_speed_scores
    return scores_at(config.speeds_m_s, v_ref_m_s, config.speed_m_s)


def scores_at(speeds_m_s: np.ndarray, v_ref_m_s: float, cruise_m_s: float) -> np.ndarray:
    """V for rollouts of ``speeds_m_s`` toward ``v_ref_m_s``."""
    return 1.0 - np.abs(speeds_m_s - v_ref_m_s) / cruise_m_s
