"""GeoJSON in: no-fly zones, stations and the area drawn in a GIS tool become mission parts.

A FeatureCollection (RFC 7946: WGS-84, coordinates ``[lon, lat]``) whose features are read by
geometry and properties:

- ``Polygon``: an obstacle (``properties.id``), or the area when ``properties.role`` is ``"area"``
  (its bounding box; ``properties.geofence_margin_m`` optional);
- ``Point`` with ``properties.radius_m``: a circle obstacle;
- ``Point`` with ``properties.station``: a named station;
- ``properties.motion`` on an obstacle: the mission's motion block, with its points as
  ``[lon, lat]`` (``{"type": "shuttle", "to": [8.55, 47.40], "speed_m_s": 3}``).

Points come out as ``{lat_deg, lon_deg}``; the mission loader converts them exactly.
"""

from __future__ import annotations

from typing import Any

from companion.formats.coords import geo_point
from uav_model.mission_errors import echo
from uav_model.mission_read import finite


class GeoJsonError(ValueError):
    """A GeoJSON document we cannot read; ``str()`` names the file, the feature and the problem."""


def _geo(pos: Any, where: str) -> dict[str, float]:
    return geo_point(pos, where, lon_first=True, error=GeoJsonError)


def _metres(value: Any, where: str) -> float:
    out = finite(value)
    if out is None or out < 0:
        raise GeoJsonError(f"{where}: expected a number of metres, got {echo(value)}")
    return out


def _ring(coords: Any, where: str) -> list[dict[str, float]]:
    if not (isinstance(coords, list) and coords and isinstance(coords[0], list)):
        raise GeoJsonError(f"{where}: a Polygon needs coordinates [[[lon, lat], ...]]")
    ring = [_geo(p, where) for p in coords[0]]
    if len(ring) >= 2 and ring[0] == ring[-1]:
        ring = ring[:-1]  # GeoJSON closes its rings; the mission does not
    if len(ring) < 3:
        raise GeoJsonError(f"{where}: a polygon needs at least 3 distinct vertices")
    return ring


def _motion(raw: Any, where: str) -> dict[str, Any]:
    if not isinstance(raw, dict):
        raise GeoJsonError(f"{where}: properties.motion must be an object")
    out = dict(raw)
    for key in ("to", "pivot"):
        if key in out:
            out[key] = _geo(out[key], f"{where}: properties.motion.{key}")
    if "waypoints" in out:
        points = out["waypoints"] if isinstance(out["waypoints"], list) else [out["waypoints"]]
        out["waypoints"] = [_geo(p, f"{where}: properties.motion.waypoints") for p in points]
    return out


def _feature(f: Any, i: int, source: str, out: dict[str, Any]) -> None:
    where = f"{source}: features[{i}]"
    if not isinstance(f, dict) or f.get("type") != "Feature" or not isinstance(f.get("geometry"), dict):
        raise GeoJsonError(f"{where}: not a GeoJSON Feature with a geometry")
    props = f.get("properties") or {}
    if not isinstance(props, dict):
        raise GeoJsonError(f"{where}: properties must be an object, got {echo(props)}")
    geom = f["geometry"]
    kind, coords = geom.get("type"), geom.get("coordinates")
    oid = str(props.get("id", props.get("name", f"feature{i}")))
    if kind == "Polygon" and props.get("role") == "area":
        ring = _ring(coords, where)
        lats, lons = [p["lat_deg"] for p in ring], [p["lon_deg"] for p in ring]
        out["area"] = {"south_west": {"lat_deg": min(lats), "lon_deg": min(lons)},
                       "north_east": {"lat_deg": max(lats), "lon_deg": max(lons)}}
        if "geofence_margin_m" in props:
            out["area"]["geofence_margin_m"] = _metres(props["geofence_margin_m"], f"{where}: properties.geofence_margin_m")
        return
    if kind == "Point" and "station" in props:
        out.setdefault("stations", {})[str(props["station"])] = _geo(coords, where)
        return
    if kind == "Polygon":
        obstacle: dict[str, Any] = {"id": oid, "shape": "polygon", "vertices": _ring(coords, where)}
    elif kind == "Point" and "radius_m" in props:
        obstacle = {"id": oid, "shape": "circle", "center": _geo(coords, where),
                    "radius_m": _metres(props["radius_m"], f"{where}: properties.radius_m")}
    else:
        raise GeoJsonError(f"{where}: a {kind if isinstance(kind, str) and len(kind) < 40 else echo(kind)} is not understood here: use a Polygon (obstacle, or role "
                           f"'area'), or a Point with properties.radius_m (circle) or properties.station")
    if "motion" in props:
        obstacle["motion"] = _motion(props["motion"], where)
    out.setdefault("obstacles", []).append(obstacle)


def geojson_to_document(doc: Any, source: str) -> dict[str, Any]:
    """Mission document parts (area, stations, obstacles) from a GeoJSON FeatureCollection."""
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise GeoJsonError(f"{source}: not a GeoJSON FeatureCollection")
    out: dict[str, Any] = {}
    features = doc.get("features") or []
    if not isinstance(features, list):
        raise GeoJsonError(f"{source}: features must be a list, got {echo(features)}")
    for i, f in enumerate(features):
        _feature(f, i, source, out)
    return out
