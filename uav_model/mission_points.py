"""Points in a mission document: ENU metres or WGS-84 lat/lon, brought to metres in one pass.

A point may be written ``[x_m, y_m]`` or ``{lat_deg, lon_deg}`` wherever the schema says
``point`` (stations, obstacle centres and vertices, motion targets), and the area by its
``south_west`` and ``north_east`` corners. :func:`localise` converts them all through
:mod:`uav_model.frames` (exact WGS-84 ENU) before the mission is built, so everything downstream
sees metres only. :func:`looks_like_latlon` catches the commonest slip: a lat/lon pair typed
where metres are expected (``[47.3977, 8.5456]`` is 47 m east, 8 m north of the origin).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from typing import Any

from uav_model.frames import GeoOrigin, geodetic_to_local

Path = list[Any]


def _point_slots(data: dict[str, Any]) -> Iterator[tuple[Path, Any]]:
    """(field path, value) of every place the schema calls a point."""
    for name, p in (data.get("stations") or {}).items():
        yield ["stations", name], p
    for i, o in enumerate(data.get("obstacles") or []):
        if not isinstance(o, dict):
            continue
        if "center" in o:
            yield ["obstacles", i, "center"], o["center"]
        for j, v in enumerate(o.get("vertices") or []):
            yield ["obstacles", i, "vertices", j], v
        motion = o.get("motion") if isinstance(o.get("motion"), dict) else {}
        for key in ("to", "pivot"):
            if key in motion:
                yield ["obstacles", i, "motion", key], motion[key]
        for k, w in enumerate(motion.get("waypoints") or []):
            yield ["obstacles", i, "motion", "waypoints", k], w


def _is_geo(p: Any) -> bool:
    return isinstance(p, dict) and "lat_deg" in p and "lon_deg" in p


def _set(data: Any, path: Path, value: Any) -> None:
    for part in path[:-1]:
        data = data[part]
    data[path[-1]] = value


def localise(data: dict[str, Any], origin: GeoOrigin) -> dict[str, Any]:
    """A copy of a schema-valid document with every lat/lon point and corner in ENU metres."""
    out = copy.deepcopy(data)
    for path, p in list(_point_slots(out)):
        if _is_geo(p):
            x, y, _ = geodetic_to_local(origin, float(p["lat_deg"]), float(p["lon_deg"]))
            _set(out, path, [x, y])
    area = out.get("area")
    if isinstance(area, dict) and _is_geo(area.get("south_west")) and _is_geo(area.get("north_east")):
        sw, ne = area.pop("south_west"), area.pop("north_east")
        area["x_min_m"], area["y_min_m"], _ = geodetic_to_local(origin, sw["lat_deg"], sw["lon_deg"])
        area["x_max_m"], area["y_max_m"], _ = geodetic_to_local(origin, ne["lat_deg"], ne["lon_deg"])
    return out


def looks_like_latlon(p: Any, origin: GeoOrigin) -> bool:
    """A metres pair that is really the origin's neighbourhood in degrees (either order)."""
    if not (isinstance(p, list) and len(p) == 2 and all(isinstance(v, (int, float)) and math.isfinite(v) for v in p)):
        return False
    a, b = float(p[0]), float(p[1])
    near = lambda u, v: abs(u - origin.lat_deg) < 1.0 and abs(v - origin.lon_deg) < 1.0  # noqa: E731
    has_decimals = any(abs(v - round(v)) > 1e-9 for v in (a, b))
    return has_decimals and (near(a, b) or near(b, a))


def latlon_slips(data: dict[str, Any], origin: GeoOrigin) -> list[tuple[Path, str]]:
    """(field path, reason) for each metres point that looks like a lat/lon pair."""
    slips = []
    for path, p in _point_slots(data):
        if looks_like_latlon(p, origin):
            lat, lon = (p[0], p[1]) if abs(p[0] - origin.lat_deg) < 1.0 else (p[1], p[0])
            slips.append((path, f"[{p[0]}, {p[1]}] looks like latitude/longitude in degrees, but a list "
                                f"is [x_m, y_m] in metres; write {{lat_deg: {lat}, lon_deg: {lon}}}"))
    return slips
