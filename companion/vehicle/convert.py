"""Conversions of MAVLink field values into port values that more than one adapter needs.

Kept free of MAVSDK so that the in-process adapter can share them; every frame relation comes
from :mod:`uav_model.frames`.
"""

from __future__ import annotations

import math

from uav_model import frames


def traffic_velocity_enu(heading_deg: float, speed_m_s: float) -> tuple[float, float]:
    """(vx_east, vy_north) from an ADS-B course (clockwise from north, a NED yaw) and speed."""
    course = frames.ned_yaw_to_enu_heading(math.radians(heading_deg))
    return speed_m_s * math.cos(course), speed_m_s * math.sin(course)
