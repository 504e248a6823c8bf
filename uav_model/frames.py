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


_A = 6_378_137.0  # WGS-84 semi-major axis, m
_E2 = 6.694_379_990_14e-3  # WGS-84 first eccentricity squared
_NEWTON_STEPS = 4


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
    """Local ENU metres to (lat_deg, lon_deg, alt_amsl_m): the exact inverse of :func:`geodetic_to_local`.

    pymap3d has the inverse too, but it costs ~2 ms a call (numpy masks on scalars), and the stub
    converts every GLOBAL_POSITION_INT it sends. So this solves geodetic_to_local(lat, lon) = (x, y)
    by Newton steps on the forward transform, from a spherical first guess; two steps reach
    well under a millimetre over a mission's few kilometres (tests/model/test_frames.py).
    """
    lat0, lon0 = origin.lat_deg, origin.lon_deg
    lat, lon = lat0, lon0
    dx, dy = x_east_m, y_north_m
    for _ in range(_NEWTON_STEPS):
        # Local radii of curvature: metres per radian of latitude (M) and of longitude (N cos lat).
        s = math.sin(math.radians(lat))
        w = math.sqrt(1.0 - _E2 * s * s)
        m_lat = _A * (1.0 - _E2) / (w * w * w)
        n_lon = _A / w * math.cos(math.radians(lat))
        lat += math.degrees(dy / m_lat)
        lon += math.degrees(dx / n_lon)
        e, n = _tangent_plane_en(origin, lat, lon)
        dx, dy = x_east_m - e, y_north_m - n
        if abs(dx) < 1e-5 and abs(dy) < 1e-5:
            break
    return lat, lon, origin.alt_m + z_up_m


def _ecef(lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    """WGS-84 geodetic to earth-centred, earth-fixed metres (pymap3d's geodetic2ecef, on floats)."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    s, c = math.sin(lat), math.cos(lat)
    n = _A / math.sqrt(1.0 - _E2 * s * s)
    return (n + alt_m) * c * math.cos(lon), (n + alt_m) * c * math.sin(lon), (n * (1.0 - _E2) + alt_m) * s


def _tangent_plane_en(origin: GeoOrigin, lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """East and north of (lat, lon) at the origin's altitude on the origin's WGS-84 tangent plane.

    pymap3d's geodetic2enu step for step (both ECEF points, their difference rotated into the
    origin's ENU axes) in plain floats: it builds an Ellipsoid and numpy masks on every call,
    ~40 us, and the stub and the companion convert every position message.
    """
    x0, y0, z0 = _ecef(origin.lat_deg, origin.lon_deg, origin.alt_m)
    x, y, z = _ecef(lat_deg, lon_deg, origin.alt_m)
    u, v, w = x - x0, y - y0, z - z0
    lat0, lon0 = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    t = math.cos(lon0) * u + math.sin(lon0) * v
    return -math.sin(lon0) * u + math.cos(lon0) * v, -math.sin(lat0) * t + math.cos(lat0) * w


def geodetic_to_local(origin: GeoOrigin, lat_deg: float, lon_deg: float,
                      alt_m: float | None = None) -> tuple[float, float, float]:
    """(lat, lon, alt AMSL) to local ENU metres: the WGS-84 tangent plane at the origin (as pymap3d).

    East and north are exact. Up is the altitude difference (flat ground at the origin's
    altitude), as PX4's local z is; the plane's curvature drop (~0.7 m at 3 km) is not applied.
    """
    e, n = _tangent_plane_en(origin, lat_deg, lon_deg)
    z = 0.0 if alt_m is None else alt_m - origin.alt_m
    return e, n, z
