"""QGroundControl ``.plan`` files: each vehicle's route and the mission's fences, out and in.

Export (:func:`plan_document`): one ``.plan`` per vehicle, shaped as QGroundControl's own plans,
from what the app uploads (the waypoints and fence zones it is given).
Its ``mission`` has the vehicle's start station as ``plannedHomePosition``, then a NAV_TAKEOFF (22)
there to cruise altitude, the route the companion uploads (NAV_WAYPOINTs at cruise altitude above
home, exactly ``FlightPlan.waypoints``) and last a NAV_LAND (21) at the goal station (a mission's
goal is never its start, so no plan ends in a return to launch). Its ``geoFence`` holds the area
plus the geofence margin as an inclusion polygon and every static obstacle, *inflated*, as an
exclusion circle or polygon: what the autopilot must never enter. These are the zones
:func:`companion.app.fence.mission_fence` gives, the ones ``companion run`` uploads. MAVSDK's
importer is stricter than QGC's documentation, so the file always has top-level ``version`` 1,
``mission.version`` 2, and ``geoFence`` and ``rallyPoints`` blocks of ``version`` 2.

Each exclusion also carries the true obstacle under the key ``astar_bdwa`` (QGC and MAVSDK ignore
unknown keys), so that importing our own file gives back the obstacle, not its inflated fence.

Import (:func:`fences_to_document`): exclusion circles and polygons become obstacles, and the
first inclusion polygon's bounding box becomes the area (without one: the box around the
stations and obstacles). The planned home and the landing (else the last waypoint) are the start
and end stations (``A`` and ``B``, or the names our own export stored), which the importer uses
when it is given no base mission. A foreign file's fences are taken as the true obstacle
footprints (they are inflated again by the mission's planner settings).
"""

from __future__ import annotations

from typing import Any

from collections.abc import Sequence

from companion.formats.coords import geo_point
from companion.vehicle.port import GeoFenceZone, GeoWaypoint
from uav_model import frames
from uav_model.mission import Mission, VehicleSpec
from uav_model.mission_errors import echo
from uav_model.mission_read import finite
from uav_model.world import Obstacle

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
QGC_FIRMWARE_PX4 = 12
QGC_VEHICLE_MULTIROTOR = 2
EXTRA_KEY = "astar_bdwa"
AREA_PAD_M = 100.0


class PlanFormatError(ValueError):
    """A ``.plan`` file we cannot read; ``str()`` names the file and the problem."""


def _latlon(origin: frames.GeoOrigin, x: float, y: float) -> list[float]:
    lat, lon, _ = frames.local_to_geodetic(origin, x, y)
    return _deg((lat, lon))


def _deg(latlon: tuple[float, float]) -> list[float]:
    return [round(latlon[0], 9), round(latlon[1], 9)]


def _true_shape(origin: frames.GeoOrigin, o: Obstacle) -> dict[str, Any]:
    if o.is_circle:
        return {"id": o.id, "shape": "circle", "center": _latlon(origin, *o.center), "radius_m": o.size_m}
    return {"id": o.id, "shape": "polygon", "vertices": [_latlon(origin, x, y) for x, y in o.vertices()]}


def _exclusion(origin: frames.GeoOrigin, o: Obstacle, zone: GeoFenceZone) -> tuple[str, dict[str, Any]]:
    extra = {EXTRA_KEY: _true_shape(origin, o)}
    if zone.is_circle:
        assert zone.center_deg is not None
        return "circles", {"circle": {"center": _deg(zone.center_deg), "radius": zone.radius_m},
                           "inclusion": False, "version": 1, **extra}
    return "polygons", {"inclusion": False, "polygon": [_deg(v) for v in zone.vertices_deg], "version": 1, **extra}


def _item(seq: int, command: int, lat_lon_alt: tuple[float | None, float | None, float]) -> dict[str, Any]:
    lat, lon, alt = lat_lon_alt
    return {"AMSLAltAboveTerrain": None, "Altitude": alt, "AltitudeMode": 1, "autoContinue": True,
            "command": command, "doJumpId": seq, "frame": MAV_FRAME_GLOBAL_RELATIVE_ALT,
            "params": [0, 0, 0, None, lat, lon, alt], "type": "SimpleItem"}


def _mission_items(origin: frames.GeoOrigin, vehicle: VehicleSpec, waypoints: Sequence[GeoWaypoint]) -> list[dict[str, Any]]:
    """Take-off at the start, the uploaded route, then land at the goal."""
    start, goal = _latlon(origin, *vehicle.start_enu_m), _latlon(origin, *vehicle.goal_enu_m)
    route = [(wp.lat_deg, wp.lon_deg, wp.alt_rel_m) for wp in waypoints]
    steps = [(MAV_CMD_NAV_TAKEOFF, (start[0], start[1], vehicle.cruise_alt_m))]
    steps += [(MAV_CMD_NAV_WAYPOINT, p) for p in route]
    steps.append((MAV_CMD_NAV_LAND, (goal[0], goal[1], 0)))  # a mission's goal is never its start
    return [_item(i + 1, command, where) for i, (command, where) in enumerate(steps)]


def plan_document(mission: Mission, vehicle: VehicleSpec, waypoints: Sequence[GeoWaypoint],
                  zones: Sequence[GeoFenceZone]) -> dict[str, Any]:
    """The QGC ``.plan`` JSON document for one vehicle of a planned mission: the ``waypoints`` the
    companion uploads (``FlightPlan.waypoints``) and the fence ``zones`` (inclusion first, then one
    exclusion per static obstacle: :func:`companion.app.fence.mission_fence`)."""
    origin = mission.origin
    w = mission.world
    sw, ne = _latlon(origin, w.x_min_m, w.y_min_m), _latlon(origin, w.x_max_m, w.y_max_m)
    area = {"area": {"south_west": {"lat_deg": sw[0], "lon_deg": sw[1]},
                     "north_east": {"lat_deg": ne[0], "lon_deg": ne[1]}, "geofence_margin_m": w.geofence_margin_m},
            "origin": {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg, "alt_m": origin.alt_m},
            "stations": {"start": vehicle.start, "goal": vehicle.goal}}
    inclusion, *exclusions = zones  # exactly what the companion uploads before arming
    fence = {"circles": [], "polygons": [{"inclusion": True, "polygon": [_deg(v) for v in inclusion.vertices_deg],
                                          "version": 1, EXTRA_KEY: area}], "version": 2}
    for o, zone in zip(mission.world.static_obstacles, exclusions, strict=True):
        kind, item = _exclusion(origin, o, zone)
        fence[kind].append(item)
    return {
        "fileType": "Plan",
        "geoFence": fence,
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": vehicle.speed_m_s, "firmwareType": QGC_FIRMWARE_PX4, "globalPlanAltitudeMode": 1,
            "hoverSpeed": vehicle.speed_m_s, "items": _mission_items(origin, vehicle, waypoints),
            "plannedHomePosition": [*_latlon(origin, *vehicle.start_enu_m), origin.alt_m],
            "vehicleType": QGC_VEHICLE_MULTIROTOR, "version": 2,
        },
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }


def _geo(pair: Any, where: str) -> dict[str, float]:
    return geo_point(pair, where, lon_first=False, error=PlanFormatError)


def _length(value: Any, where: str) -> float:
    out = finite(value)
    if out is None or out <= 0:
        raise PlanFormatError(f"{where}: expected a positive number of metres, got {echo(value)}")
    return out


def _obstacle_from_extra(extra: Any, where: str) -> dict[str, Any]:
    where = f"{where}.{EXTRA_KEY}"
    if not isinstance(extra, dict) or extra.get("shape") not in ("circle", "polygon") or "id" not in extra:
        raise PlanFormatError(f"{where}: expected {{id, shape: circle|polygon, ...}}, got {echo(extra)}")
    out = {"id": str(extra["id"]), "shape": extra["shape"]}
    if extra["shape"] == "circle":
        out.update(center=_geo(extra.get("center"), f"{where}.center"),
                   radius_m=_length(extra.get("radius_m"), f"{where}.radius_m"))
    else:
        out["vertices"] = [_geo(v, f"{where}.vertices[{j}]") for j, v in enumerate(_items(extra.get("vertices"), where))]
    return out


def _items(value: Any, where: str) -> list[Any]:
    """A list the file must hold (null and absent: none)."""
    if value is None:
        return []
    if not isinstance(value, list):
        raise PlanFormatError(f"{where}: expected a list, got {echo(value)}")
    return value


def _block(value: Any, where: str) -> dict[str, Any]:
    """An object the file must hold (null and absent: empty)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise PlanFormatError(f"{where}: expected an object, got {echo(value)}")
    return value


def fences_to_document(doc: Any, source: str) -> dict[str, Any]:
    """Mission document parts (origin, area, obstacles) from a ``.plan``'s geofence, in lat/lon."""
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise PlanFormatError(f"{source}: not a QGroundControl plan (fileType is not 'Plan')")
    fence = _block(doc.get("geoFence"), f"{source}: geoFence")
    out: dict[str, Any] = {"obstacles": []}
    names: dict[str, str] = {}  # our own export's station names
    home = _block(doc.get("mission"), f"{source}: mission").get("plannedHomePosition")
    if home is not None:
        where = f"{source}: mission.plannedHomePosition"
        out["origin"] = _geo(home, where)
        if len(home) >= 3 and home[2] is not None:  # QGC writes null for an unknown altitude
            if finite(home[2]) is None:
                raise PlanFormatError(f"{where}: expected an altitude in metres, got {echo(home[2])}")
            out["origin"]["alt_m"] = finite(home[2])
    for i, c in enumerate(_items(fence.get("circles"), f"{source}: geoFence.circles")):
        where = f"{source}: geoFence.circles[{i}]"
        c = _block(c, where)
        if c.get("inclusion"):
            continue
        if EXTRA_KEY in c:
            out["obstacles"].append(_obstacle_from_extra(c[EXTRA_KEY], where))
            continue
        circle = _block(c.get("circle"), f"{where}.circle")
        out["obstacles"].append({"id": f"fence_circle{i}", "shape": "circle",
                                 "center": _geo(circle.get("center"), f"{where}.circle.center"),
                                 "radius_m": _length(circle.get("radius"), f"{where}.circle.radius")})
    for i, p in enumerate(_items(fence.get("polygons"), f"{source}: geoFence.polygons")):
        where = f"{source}: geoFence.polygons[{i}]"
        p = _block(p, where)
        ring = [_geo(v, f"{where}.polygon[{j}]") for j, v in enumerate(_items(p.get("polygon"), f"{where}.polygon"))]
        if p.get("inclusion"):
            if "area" not in out and isinstance(p.get(EXTRA_KEY), dict) and "area" in p[EXTRA_KEY]:
                out["area"] = p[EXTRA_KEY]["area"]
                out["origin"] = p[EXTRA_KEY].get("origin", out.get("origin"))
                names = p[EXTRA_KEY].get("stations", names)
            elif "area" not in out and ring:
                lats = [v["lat_deg"] for v in ring]
                lons = [v["lon_deg"] for v in ring]
                out["area"] = {"south_west": {"lat_deg": min(lats), "lon_deg": min(lons)},
                               "north_east": {"lat_deg": max(lats), "lon_deg": max(lons)},
                               "geofence_margin_m": 0.0}
            continue
        if EXTRA_KEY in p:
            out["obstacles"].append(_obstacle_from_extra(p[EXTRA_KEY], where))
        else:
            out["obstacles"].append({"id": f"fence_polygon{i}", "shape": "polygon", "vertices": ring})
    ends = _route_ends(doc.get("mission") or {}, source, names.get("start", "A"), names.get("goal", "B"))
    if ends is not None:
        out["route_stations"] = ends
    if "area" not in out and "origin" in out:
        out["area"] = _area_around(out, ends)
    return out


def _area_around(parts: dict[str, Any], ends: dict[str, dict[str, float]] | None) -> dict[str, Any]:
    """A foreign plan without an inclusion fence: the box around its stations and obstacles, plus
    a tenth of its size (at least AREA_PAD_M) on every side."""
    o = parts["origin"]
    origin = frames.GeoOrigin(o["lat_deg"], o["lon_deg"], o.get("alt_m", 0.0))
    xy = [(0.0, 0.0)]

    def add(p: dict[str, float], r: float = 0.0) -> None:
        x, y, _ = frames.geodetic_to_local(origin, p["lat_deg"], p["lon_deg"])
        xy.extend([(x - r, y - r), (x + r, y + r)])
    for p in (ends or {}).values():
        add(p)
    for ob in parts["obstacles"]:
        for v in ob.get("vertices", []):
            add(v)
        if "center" in ob:
            add(ob["center"], ob["radius_m"])
    xs, ys = [p[0] for p in xy], [p[1] for p in xy]
    pad = max(0.1 * max(max(xs) - min(xs), max(ys) - min(ys)), AREA_PAD_M)
    sw = frames.local_to_geodetic(origin, min(xs) - pad, min(ys) - pad)
    ne = frames.local_to_geodetic(origin, max(xs) + pad, max(ys) + pad)
    return {"south_west": {"lat_deg": round(sw[0], 9), "lon_deg": round(sw[1], 9)},
            "north_east": {"lat_deg": round(ne[0], 9), "lon_deg": round(ne[1], 9)}}


def _route_ends(mission: dict[str, Any], source: str, start: str, goal: str) -> dict[str, dict[str, float]] | None:
    """The start station (the planned home) and the goal (the landing, else the last waypoint),
    named as our own export names them (else A and B); None when the plan has no such two."""
    home = mission.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) >= 2):
        return None
    end = None
    for i, item in enumerate(mission.get("items") or []):
        if not isinstance(item, dict) or item.get("type") != "SimpleItem" \
                or item.get("command") not in (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LAND):
            continue
        params = item.get("params")
        if not isinstance(params, list) or len(params) < 6 or not params[4] or not params[5]:
            continue  # no position (e.g. a land "here"): it names no end
        end = _geo(params[4:6], f"{source}: mission.items[{i}].params")
        if item["command"] == MAV_CMD_NAV_LAND:
            break
    home_geo = _geo(home[:2], f"{source}: mission.plannedHomePosition")
    return None if end is None or end == home_geo else {start: home_geo, goal: end}
