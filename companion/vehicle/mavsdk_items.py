"""The port's values as MAVSDK's (mission items, body-frame setpoints) and back, for the MAVSDK adapter.

Pure conversions: frames only through :mod:`uav_model.frames`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from mavsdk.asyncio.plugins.mission_raw import MissionItem
from mavsdk.asyncio.plugins.offboard import VelocityBodyYawspeed

from companion.vehicle.port import GeoWaypoint, VelocityYawRateSetpoint
from uav_model import frames

MAV_CMD_NAV_WAYPOINT = 16
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_MISSION_TYPE_MISSION = 0
MAV_MISSION_TYPE_FENCE = 1


def waypoints_to_items(waypoints: Sequence[GeoWaypoint], acceptance_radius_m: float) -> list[MissionItem]:
    """MISSION_ITEM_INT NAV_WAYPOINTs (lat/lon in 1e-7 degrees, altitude above home)."""
    return [MissionItem(seq=i, frame=MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command=MAV_CMD_NAV_WAYPOINT,
                        current=1 if i == 0 else 0, autocontinue=1,
                        param1=0.0, param2=float(acceptance_radius_m), param3=0.0, param4=float("nan"),
                        x=int(round(w.lat_deg * 1e7)), y=int(round(w.lon_deg * 1e7)), z=float(w.alt_rel_m),
                        mission_type=MAV_MISSION_TYPE_MISSION)
            for i, w in enumerate(waypoints)]


def items_to_waypoints(items: Sequence[MissionItem]) -> tuple[GeoWaypoint, ...]:
    return tuple(GeoWaypoint(lat_deg=it.x / 1e7, lon_deg=it.y / 1e7, alt_rel_m=float(it.z))
                 for it in items if it.command == MAV_CMD_NAV_WAYPOINT)


def body_setpoint(sp: VelocityYawRateSetpoint) -> VelocityBodyYawspeed:
    """The port's setpoint as MAVSDK's BODY_NED velocity + PX4 (clockwise) yawspeed."""
    yawspeed = frames.enu_yaw_rate_to_ned(sp.yaw_rate_enu_rad_s)
    return VelocityBodyYawspeed(forward_m_s=float(sp.forward_m_s), right_m_s=0.0,
                                down_m_s=float(-sp.climb_m_s), yawspeed_deg_s=math.degrees(yawspeed))
