"""Conversions between MAVLink field values and port values that more than one adapter needs.

Kept free of MAVSDK so that the in-process adapter can share them; every frame relation comes
from :mod:`uav_model.frames`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import takewhile

from uav_model import frames
from companion.vehicle.port import GeoFenceZone


def traffic_velocity_enu(heading_deg: float, speed_m_s: float) -> tuple[float, float]:
    """(vx_east, vy_north) from an ADS-B course (clockwise from north, a NED yaw) and speed."""
    course = frames.ned_yaw_to_enu_heading(math.radians(heading_deg))
    return speed_m_s * math.cos(course), speed_m_s * math.sin(course)


# MAVLink fence commands (MAV_CMD_NAV_FENCE_*), by kind and inclusion.
FENCE_POLYGON_INCLUSION = 5001
FENCE_POLYGON_EXCLUSION = 5002
FENCE_CIRCLE_INCLUSION = 5003
FENCE_CIRCLE_EXCLUSION = 5004
MAV_FRAME_GLOBAL = 0  # fence items carry lat/lon only; PX4 and QGroundControl send this frame


@dataclass(frozen=True, slots=True)
class FenceItem:
    """One MISSION_ITEM_INT of a FENCE plan: a polygon vertex (param1 = vertex count) or a circle
    (param1 = radius, m); lat/lon in 1e-7 degrees."""

    command: int
    param1: float
    lat_e7: int
    lon_e7: int


def _e7(deg: float) -> int:
    return int(round(deg * 1e7))


def fence_items(zones: Sequence[GeoFenceZone]) -> list[FenceItem]:
    """The FENCE plan of ``zones``, in order: each polygon as its run of vertices, each circle as one item."""
    out: list[FenceItem] = []
    for z in zones:
        if z.is_circle:
            assert z.center_deg is not None
            cmd = FENCE_CIRCLE_INCLUSION if z.inclusion else FENCE_CIRCLE_EXCLUSION
            out.append(FenceItem(cmd, float(z.radius_m), _e7(z.center_deg[0]), _e7(z.center_deg[1])))
            continue
        cmd = FENCE_POLYGON_INCLUSION if z.inclusion else FENCE_POLYGON_EXCLUSION
        out += [FenceItem(cmd, float(len(z.vertices_deg)), _e7(lat), _e7(lon)) for lat, lon in z.vertices_deg]
    return out


def fence_zones(items: Sequence[FenceItem]) -> tuple[GeoFenceZone, ...]:
    """The zones a downloaded FENCE plan holds (other items, such as a return point, are skipped).
    A polygon's run ends after ``param1`` vertices or where the command changes."""
    out: list[GeoFenceZone] = []
    i = 0
    while i < len(items):
        it = items[i]
        if it.command in (FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION):
            out.append(GeoFenceZone(inclusion=it.command == FENCE_CIRCLE_INCLUSION,
                                    center_deg=(it.lat_e7 / 1e7, it.lon_e7 / 1e7), radius_m=float(it.param1)))
            i += 1
        elif it.command in (FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION):
            run = list(takewhile(lambda r: r.command == it.command, items[i:i + max(int(it.param1), 1)]))
            out.append(GeoFenceZone(inclusion=it.command == FENCE_POLYGON_INCLUSION,
                                    vertices_deg=tuple((r.lat_e7 / 1e7, r.lon_e7 / 1e7) for r in run)))
            i += len(run)
        else:
            i += 1
    return tuple(out)
