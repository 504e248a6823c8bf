"""The plant's values: state and command in PX4's local NED frame, shared by every plant.

North, east, down; yaw clockwise from north, because this is the autopilot's side of the link.
Callers in the ENU mission frame convert with :mod:`uav_model.frames`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class VelocityFrame(Enum):
    LOCAL_NED = "local_ned"
    BODY_NED = "body_ned"  # x forward, y right, z down; rotated by yaw only (PX4 MAV_FRAME_BODY_NED)


@dataclass(frozen=True, slots=True)
class KinematicState:
    north_m: float
    east_m: float
    down_m: float
    vn_m_s: float = 0.0
    ve_m_s: float = 0.0
    vd_m_s: float = 0.0
    yaw_rad: float = 0.0  # NED yaw, wrapped to [-pi, pi)
    yawspeed_rad_s: float = 0.0  # heading rate
    # The multicopter's inner state (multicopter.py); the unicycle leaves them at 0.
    accel_n_m_s2: float = 0.0  # horizontal acceleration the thrust produces (the tilt)
    accel_e_m_s2: float = 0.0
    vel_int_n_m_s2: float = 0.0  # the velocity controller's integrator
    vel_int_e_m_s2: float = 0.0

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(self.vn_m_s, self.ve_m_s)


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """Velocity + yawspeed setpoint. In BODY_NED, x is forward and y is right."""

    frame: VelocityFrame
    x_m_s: float
    y_m_s: float
    z_m_s: float  # down-positive in both frames
    yawspeed_rad_s: float  # clockwise-positive (PX4)


HOVER = VelocityCommand(VelocityFrame.LOCAL_NED, 0.0, 0.0, 0.0, 0.0)
