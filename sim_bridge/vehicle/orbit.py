"""MAV_CMD_DO_ORBIT: PX4's multicopter ORBIT mode (POSCTL main mode, ORBIT sub mode). Pure geometry.

PX4 flies a circle around a centre at a tangential speed, clockwise for a positive radius and
counter-clockwise for a negative one, holding the centre's altitude; a NaN speed, centre or
altitude keeps PX4's default (1 m/s, the current position, the current altitude). The radius is
clamped to [1 m, MC_ORBIT_RAD_MAX]; the orbit goes on until another mode is commanded (PX4 does
not count param4's orbits either).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import wrap_pi
from uav_model.plant import KinematicState, VehicleLimits, VelocityCommand, VelocityFrame
from sim_bridge.vehicle.types import KP_ALTITUDE_1_S, KP_POSITION_1_S, clip

DEFAULT_SPEED_M_S = 1.0  # PX4 FlightTaskOrbit's default tangential speed
MIN_RADIUS_M = 1.0


class OrbitYaw(IntEnum):
    """MAVLink ORBIT_YAW_BEHAVIOUR."""

    FRONT_TO_CENTER = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TO_CIRCLE_CENTER
    INITIAL_HEADING = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_INITIAL_HEADING
    UNCONTROLLED = mavlink.ORBIT_YAW_BEHAVIOUR_UNCONTROLLED
    FRONT_TANGENT = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TANGENT_TO_CIRCLE
    RC_CONTROLLED = mavlink.ORBIT_YAW_BEHAVIOUR_RC_CONTROLLED


@dataclass(frozen=True, slots=True)
class Orbit:
    """One commanded orbit, in the local NED frame. ``radius_m`` > 0: clockwise seen from above."""

    center_n_m: float
    center_e_m: float
    down_m: float
    radius_m: float
    speed_m_s: float
    yaw: OrbitYaw
    initial_yaw_rad: float


def make_orbit(state: KinematicState, radius_m: float, speed_m_s: float, yaw_behaviour: float,
               center_ne: tuple[float, float] | None, down_m: float | None, max_radius_m: float) -> Orbit | None:
    """The orbit a DO_ORBIT asks for, or None when its radius is unusable."""
    if not math.isfinite(radius_m) or radius_m == 0.0:
        return None
    radius = math.copysign(clip(abs(radius_m), MIN_RADIUS_M, max(max_radius_m, MIN_RADIUS_M)), radius_m)
    speed = abs(speed_m_s) if math.isfinite(speed_m_s) and speed_m_s != 0.0 else DEFAULT_SPEED_M_S
    try:
        yaw = OrbitYaw(int(yaw_behaviour)) if math.isfinite(yaw_behaviour) else OrbitYaw.FRONT_TO_CENTER
    except ValueError:
        yaw = OrbitYaw.FRONT_TO_CENTER
    cn, ce = center_ne if center_ne is not None else (state.north_m, state.east_m)
    return Orbit(cn, ce, state.down_m if down_m is None else down_m, radius, speed, yaw, state.yaw_rad)


def orbit_command(orbit: Orbit, state: KinematicState, limits: VehicleLimits, dt_s: float) -> VelocityCommand:
    """Velocity along the circle plus a radial and a height correction; the yaw the behaviour asks."""
    dn, de = state.north_m - orbit.center_n_m, state.east_m - orbit.center_e_m
    dist = math.hypot(dn, de)
    un, ue = (dn / dist, de / dist) if dist > 1e-6 else (math.cos(state.yaw_rad), math.sin(state.yaw_rad))
    direction = 1.0 if orbit.radius_m > 0 else -1.0
    tn, te = -ue * direction, un * direction  # clockwise tangent in NED for a positive radius
    radius = abs(orbit.radius_m)
    speed = min(orbit.speed_m_s, limits.max_speed_m_s)
    radial = KP_POSITION_1_S * (radius - dist)
    vn, ve = speed * tn + radial * un, speed * te + radial * ue
    norm = math.hypot(vn, ve)
    if norm > limits.max_speed_m_s:
        vn, ve = vn * limits.max_speed_m_s / norm, ve * limits.max_speed_m_s / norm
    vd = clip(KP_ALTITUDE_1_S * (orbit.down_m - state.down_m), -limits.max_climb_m_s, limits.max_climb_m_s)
    turn_rate = direction * speed / radius  # the heading change that keeps a face-to-centre yaw
    if orbit.yaw is OrbitYaw.FRONT_TO_CENTER:
        target = math.atan2(-ue, -un)
    elif orbit.yaw is OrbitYaw.FRONT_TANGENT:
        target = math.atan2(te, tn)
    elif orbit.yaw is OrbitYaw.INITIAL_HEADING:
        target, turn_rate = orbit.initial_yaw_rad, 0.0
    else:
        return VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, vd, 0.0)
    err = wrap_pi(target - state.yaw_rad)
    yawspeed = clip(turn_rate + err / max(dt_s, 1e-3) * 0.2, -limits.max_yaw_rate_rad_s, limits.max_yaw_rate_rad_s)
    return VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, vd, yawspeed)
