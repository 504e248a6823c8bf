"""The one place where frames and angle conventions are converted.

Mission and planner frame: local ENU metres (x east, y north) from the mission's geodetic
origin; headings are math angles (from +x, counter-clockwise).
MAVLink / PX4 frame: NED (north, east, down); yaw is clockwise from north.

    north = y,  east = x,  down = -up,  yaw_ned = pi/2 - theta_enu

A yaw *rate* therefore flips sign between the two frames. Every other module converts through
these functions; none re-derives the relation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6_378_137.0  # WGS-84 equatorial radius, as PX4's map_projection uses


@dataclass(frozen=True, slots=True)
class GeoOrigin:
    """Geodetic origin of the local frame (WGS-84, AMSL altitude)."""

    lat_deg: float
    lon_deg: float
    alt_m: float


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def enu_heading_to_ned_yaw(theta_enu_rad: float) -> float:
    """Math heading (from +x east, CCW) to NED yaw (from north, CW), wrapped to [-pi, pi)."""
    return wrap_pi(math.pi / 2.0 - theta_enu_rad)


def ned_yaw_to_enu_heading(yaw_ned_rad: float) -> float:
    """NED yaw (from north, CW) to math heading (from +x east, CCW), wrapped to [-pi, pi)."""
    return wrap_pi(math.pi / 2.0 - yaw_ned_rad)


def enu_yaw_rate_to_ned(omega_enu_rad_s: float) -> float:
    """CCW-positive yaw rate to PX4's CW-positive yawspeed."""
    return -omega_enu_rad_s


def ned_yaw_rate_to_enu(yawspeed_ned_rad_s: float) -> float:
    """PX4's CW-positive yawspeed to a CCW-positive yaw rate."""
    return -yawspeed_ned_rad_s


def enu_to_ned(x_east_m: float, y_north_m: float, z_up_m: float = 0.0) -> tuple[float, float, float]:
    """ENU position or vector to NED (north, east, down)."""
    return y_north_m, x_east_m, -z_up_m


def ned_to_enu(north_m: float, east_m: float, down_m: float = 0.0) -> tuple[float, float, float]:
    """NED position or vector to ENU (x east, y north, z up)."""
    return east_m, north_m, -down_m


def local_to_geodetic(origin: GeoOrigin, x_east_m: float, y_north_m: float,
                      z_up_m: float = 0.0) -> tuple[float, float, float]:
    """Local ENU metres to (lat_deg, lon_deg, alt_amsl_m) by azimuthal equidistant projection.

    This is the projection PX4 uses for its local frame (map_projection); it is exact to well
    under a metre over the few kilometres a mission spans.
    """
    lat0 = math.radians(origin.lat_deg)
    lon0 = math.radians(origin.lon_deg)
    x_rad = x_east_m / EARTH_RADIUS_M
    y_rad = y_north_m / EARTH_RADIUS_M
    c = math.hypot(x_rad, y_rad)
    if c < 1e-12:
        return origin.lat_deg, origin.lon_deg, origin.alt_m + z_up_m
    sin_c, cos_c = math.sin(c), math.cos(c)
    lat = math.asin(cos_c * math.sin(lat0) + y_rad * sin_c * math.cos(lat0) / c)
    lon = lon0 + math.atan2(x_rad * sin_c,
                            c * math.cos(lat0) * cos_c - y_rad * math.sin(lat0) * sin_c)
    return math.degrees(lat), math.degrees(lon), origin.alt_m + z_up_m


def geodetic_to_local(origin: GeoOrigin, lat_deg: float, lon_deg: float,
                      alt_m: float | None = None) -> tuple[float, float, float]:
    """(lat, lon, alt AMSL) to local ENU metres; the inverse of :func:`local_to_geodetic`."""
    lat0 = math.radians(origin.lat_deg)
    lon0 = math.radians(origin.lon_deg)
    lat = math.radians(lat_deg)
    lon = math.radians(lon_deg)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    cos_dlon = math.cos(lon - lon0)
    arg = math.sin(lat0) * sin_lat + math.cos(lat0) * cos_lat * cos_dlon
    arg = max(-1.0, min(1.0, arg))
    c = math.acos(arg)
    k = 1.0 if abs(c) < 1e-12 else c / math.sin(c)
    x = k * cos_lat * math.sin(lon - lon0) * EARTH_RADIUS_M
    y = k * (math.cos(lat0) * sin_lat - math.sin(lat0) * cos_lat * cos_dlon) * EARTH_RADIUS_M
    z = 0.0 if alt_m is None else alt_m - origin.alt_m
    return x, y, z
