"""How far the autopilot's geofence lies beyond the planner's keep-out and keep-in: one number for both.

    braking_distance_m(mission, vehicle)   v^2 / (2 a): how far the vehicle flies once it brakes
    fence_standoff_m(mission)              the largest of them: the fence's standoff
    px4_braking_reach_m(speed_m_s)         PX4's own multicopter stopping distance (its predictive fence)
    keep_in_standoff_m(mission)            how far the rollouts keep from the inclusion fence
    keep_in_box(world)                     the declared area: no route leaves it
    rollout_box(mission, vehicle)          where the local planner's rollouts may go: the area,
                                           or more of the geofence margin where it is wide
    exclusion_margin_m(obstacle, standoff) how far an uploaded exclusion lies outside the footprint
    fence_warnings(mission)                the margins too thin for the full standoff

PX4 takes the geofence action when the position (or, with GF_PREDICT 1, the braking point
v^2 / (2 MPC_ACC_HOR) ahead) crosses the fence, and its Hold then brakes over that distance. The
planner keeps out of the inflated obstacles and inside the area; the fence the companion uploads
lies the standoff beyond both, so a flight that keeps to its plan never triggers it, predictive or
not. The local planner's rollouts (11 s ahead in the paper's setting) may swing past a station on
the area's edge into the geofence margin, but never closer to the inclusion fence than the
keep-in standoff plus what the plant may stray from them (``TRACKING_LAG_S`` at cruise speed).

The keep-in standoff of the multicopter is PX4's own stopping distance, the one its navigator
tests ahead of the vehicle with GF_PREDICT 1: a jerk-limited stop (MPC_JERK_AUTO) at MPC_ACC_HOR
from a vehicle still accelerating at MPC_ACC_HOR_MAX, plus one 0.2 s fence check at speed: 50.7 m
at 10 m/s with PX4's defaults, three times v^2 / (2 MPC_ACC_HOR). Measured on PX4 SIH (GF_PREDICT
0, its default), a vehicle circling a station on the area's corner flew 36 m past rollouts kept
v^2 / (2 a) plus the lag from the fence, and met it. ``a`` is the plant's braking acceleration: PX4's MPC_ACC_HOR (default 3 m/s^2) for the
multicopter, the mission's ``max_accel_m_s2`` for the unicycle (the stub's Hold brakes with the same).

Where a margin is thinner than the standoff the fence does not move inside it: an obstacle's
exclusion is never smaller than its footprint, and the area's inclusion is the area plus
``geofence_margin_m`` as declared. ``fence_warnings`` names each such place.
"""

from __future__ import annotations

from uav_model.mission_types import Mission, VehicleSpec
from uav_model.plant import TRACKING_LAG_S, Plant, limits_for
from uav_model.world import Obstacle, World

# PX4's defaults for its multicopter stopping model (the navigator's predictive geofence)
PX4_ACC_HOR = 3.0  # MPC_ACC_HOR, m/s^2: the braking deceleration
PX4_ACC_HOR_MAX = 5.0  # MPC_ACC_HOR_MAX, m/s^2: the forward acceleration the stop starts from
PX4_JERK_AUTO = 4.0  # MPC_JERK_AUTO, m/s^3
PX4_FENCE_CHECK_S = 0.2  # the navigator checks its geofence every 200 ms


def braking_distance_m(mission: Mission, vehicle: VehicleSpec) -> float:
    """v^2 / (2 a) at the vehicle's cruise speed, with the plant's braking acceleration."""
    limits = limits_for(mission.plant, speed_m_s=vehicle.speed_m_s, max_yaw_rate_rad_s=vehicle.max_yaw_rate_rad_s,
                        max_accel_m_s2=vehicle.max_accel_m_s2)
    return vehicle.speed_m_s ** 2 / (2.0 * limits.max_accel_m_s2)


def fence_standoff_m(mission: Mission) -> float:
    """The distance the uploaded fence keeps beyond the planner's keep-out and keep-in."""
    return max((braking_distance_m(mission, v) for v in mission.vehicles), default=0.0)


def px4_braking_reach_m(speed_m_s: float, acc_hor_m_s2: float = PX4_ACC_HOR, acc_hor_max_m_s2: float = PX4_ACC_HOR_MAX,
                        jerk_m_s3: float = PX4_JERK_AUTO) -> float:
    """How far PX4 reckons a multicopter at ``speed_m_s`` flies before it stops: the acceleration
    ramps with the jerk limit from +max(acc_hor, acc_hor_max) to -acc_hor, holds, and ramps back
    to 0 as the speed reaches 0; then one fence check interval at the speed (PX4's navigator)."""
    v, a0, a_max, j = float(speed_m_s), max(acc_hor_m_s2, acc_hor_max_m_s2), acc_hor_m_s2, jerk_m_s3
    if v <= 0.0:
        return 0.0
    # the deceleration reached: a_max, or less when the speed runs out first (a triangular ramp)
    a_peak = min(a_max, (j * v + 0.5 * a0 * a0) ** 0.5)
    hold_s = max(0.0, (v + 0.5 * a0 * a0 / j - a_peak * a_peak / j) / a_max)
    pos, vel, acc = 0.0, v, a0
    for jerk, t in ((-j, (a0 + a_peak) / j), (0.0, hold_s), (j, a_peak / j)):
        pos += vel * t + 0.5 * acc * t * t + jerk * t ** 3 / 6.0
        vel += acc * t + 0.5 * jerk * t * t
        acc += jerk * t
    return pos + PX4_FENCE_CHECK_S * v


def keep_in_standoff_m(mission: Mission) -> float:
    """How far the local planner's rollouts keep from the inclusion fence, before the tracking lag:
    PX4's stopping distance at cruise speed on the multicopter, the braking distance on the unicycle."""
    if mission.plant is Plant.MULTICOPTER:
        return max((px4_braking_reach_m(v.speed_m_s) for v in mission.vehicles), default=0.0)
    return fence_standoff_m(mission)


def keep_in_box(world: World) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1): the declared area, which routes and rollouts stay inside."""
    return world.x_min_m, world.y_min_m, world.x_max_m, world.y_max_m


def rollout_box(mission: Mission, vehicle: VehicleSpec) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1): the keep-in grown into the geofence margin by what is left of it once
    the keep-in standoff and the plant's tracking lag are kept from the fence (never less than the area)."""
    grow = max(0.0, mission.world.geofence_margin_m - keep_in_standoff_m(mission)
               - TRACKING_LAG_S[mission.plant] * vehicle.speed_m_s)
    x0, y0, x1, y1 = keep_in_box(mission.world)
    return x0 - grow, y0 - grow, x1 + grow, y1 + grow


def exclusion_margin_m(obstacle: Obstacle, standoff_m: float) -> float:
    """The uploaded exclusion is the footprint grown by this: the inflation less the standoff,
    never less than nothing."""
    return max(0.0, obstacle.margin_m - standoff_m)


def fence_warnings(mission: Mission) -> list[str]:
    """One line per fence margin thinner than the standoff (empty when all are wide enough)."""
    s = fence_standoff_m(mission)
    out = []
    world = mission.world
    if world.geofence_margin_m < s:
        out.append(f"area.geofence_margin_m {world.geofence_margin_m:g} m is less than the {s:.1f} m a vehicle "
                   f"needs to brake: the fence lies only that far beyond the area the planner keeps to")
    for o in world.static_obstacles:
        if o.margin_m < s:
            out.append(f"obstacle {o.id!r}: its inflation {o.margin_m:.1f} m is less than the {s:.1f} m braking "
                       f"distance: its exclusion fence is the footprint, {o.margin_m:.1f} m inside the keep-out")
    return out
