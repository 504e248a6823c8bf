"""Mission files: the one loader, the published JSON Schema, and the typed objects they become.

Validation happens here and only here (SPEC §5). A bad file raises :class:`MissionError`, whose
message names the file, the line and the field path; everything downstream receives frozen,
already-valid objects.

The typed objects are in :mod:`uav_model.mission_types`, what a MissionError reports and how its
lines are found in :mod:`uav_model.mission_errors`, how a file is read within its limits
(:mod:`uav_model.mission_limits`) in :mod:`uav_model.mission_read`; import them all from here.

Numbers are finite everywhere: NaN and infinity fail the schema's ``number`` type
(:mod:`uav_model.mission_validator`).
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass, fields
from functools import lru_cache
from pathlib import Path
from typing import Any

import jsonschema
import yaml
from shapely.geometry import Point

from uav_model.frames import GeoOrigin
from uav_model.mission_errors import MissionError, dotted, fail, innermost, line_of, schema_reason
from uav_model.mission_limits import MAX_GRID_CELLS, grid_shape
from uav_model.mission_points import latlon_slips, localise
from uav_model.mission_read import load_yaml, mission_error, read_text
from uav_model.mission_schema import mission_schema, schema_default
from uav_model.mission_sightline import assigned_pairs
from uav_model.mission_validator import mission_validator
from uav_model.mission_types import (VARIANTS, CoordinationSettings, Forecast, Mission, Normalisation, PlannerSettings,
                                     SafetySettings, SightlineCritic, SpawnHeading, Variant, VehicleSpec, shared_goals)
from uav_model.plant import Plant
from uav_model.world import Obstacle, Orbit, Patrol, Shuttle, Static, World, make_obstacle

__all__ = ["API_PORT_BASE", "CoordinationSettings", "DEFAULT_ORIGIN", "Forecast", "VARIANTS", "Mission", "MissionError",
           "Normalisation", "PlannerSettings", "SafetySettings", "SightlineCritic", "SpawnHeading", "Variant", "VehicleSpec",
           "load_mission", "mission_error",
           "mission_from_data", "mission_schema", "parse_mission", "shared_goals"]

DEFAULT_ORIGIN = GeoOrigin(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)  # PX4 SITL home
API_PORT_BASE = 14540  # PX4 SITL: vehicle i talks to the companion on 14540 + i


@lru_cache(maxsize=1)
def _validator() -> jsonschema.protocols.Validator:
    """The published schema's validator (:mod:`uav_model.mission_validator`: finite numbers)."""
    return mission_validator(mission_schema())


def load_mission(path: str | Path) -> Mission:
    """Read, validate and type a mission file. Raises MissionError, never anything else."""
    return parse_mission(read_text(path), str(path))


def parse_mission(text: str, source: str = "<mission>") -> Mission:
    """Validate and type mission YAML text; ``source`` names it in errors."""
    data, root = load_yaml(text, source)
    if not isinstance(data, dict):
        raise MissionError(source, "", "a mission file must be a YAML mapping", line_of(root, []))
    return _validated(data, source, root)


def mission_from_data(data: dict[str, Any], source: str = "<mission>") -> Mission:
    """A mission document already in memory (JSON types: dicts, lists, numbers, strings), e.g.
    from the scenario generator: the same validation as :func:`parse_mission`, without a YAML
    round trip (errors then carry no line number)."""
    if not isinstance(data, dict):
        raise MissionError(source, "", "a mission document must be a mapping")
    return _validated(data, source, None)


def _schema_problems(data: dict[str, Any], source: str, root: yaml.Node | None) -> list[MissionError]:
    """Every schema violation, one per field (not only the first)."""
    problems: dict[str, MissionError] = {}
    for err in _validator().iter_errors(data):
        path, reason = schema_reason(innermost(err))
        problems.setdefault(dotted(path), MissionError(source, dotted(path), reason, line_of(root, path)))
    return list(problems.values())


def _validated(data: dict[str, Any], source: str, root: yaml.Node | None) -> Mission:
    """Check the whole document and report every problem at once (``MissionError.problems``)."""
    problems = _schema_problems(data, source, root)
    origin = _origin(data.get("origin")) if not any(p.field_path.startswith("origin") for p in problems) else DEFAULT_ORIGIN
    problems += [fail(source, root, path, reason) for path, reason in latlon_slips(data, origin)]
    found: list[MissionError] = []
    mission = None
    try:
        broken = {re.match(r"^[a-z_]+(\[\d+\])?", p.field_path).group(0) for p in problems if p.field_path}
        mission = _build(localise(data, origin), source, root, origin, found, broken)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, ArithmeticError):
        if not problems and not found:  # a valid document must build: our bug, not the file's
            raise
    problems += found
    if problems:
        raise MissionError.of(problems)
    assert mission is not None
    return mission


def _origin(raw: dict[str, Any] | None) -> GeoOrigin:
    if raw is None:
        return DEFAULT_ORIGIN
    return GeoOrigin(float(raw["lat_deg"]), float(raw["lon_deg"]), float(raw.get("alt_m", DEFAULT_ORIGIN.alt_m)))


def _motion(spec: dict | None, start: tuple[float, float]):
    if not spec or spec["type"] == "static":
        return Static()
    kind = spec["type"]
    speed = float(spec["speed_m_s"])
    if kind == "shuttle":
        to = spec["to"]
        return Shuttle(delta_m=(to[0] - start[0], to[1] - start[1]), speed_m_s=speed)
    if kind == "orbit":
        return Orbit(pivot_m=tuple(spec["pivot"]), start_m=start, speed_m_s=speed,
                     clockwise=bool(spec.get("clockwise", False)))
    return Patrol(loop_m=(start,) + tuple(tuple(p) for p in spec["waypoints"]), speed_m_s=speed)


def _opt(raw: dict, defs: dict, key: str):
    """A field's value, or the schema's default for it."""
    return raw.get(key, defs[key].get("default"))


@dataclass
class _Problems:
    """Semantic problems found while building, each at its field's line."""

    source: str
    root: yaml.Node | None
    found: list[MissionError]

    def add(self, path: list[Any], reason: str) -> None:
        self.found.append(fail(self.source, self.root, path, reason))


def _build(data: dict, source: str, root: yaml.Node | None, origin: GeoOrigin,
           problems: list[MissionError], broken: set[str] = frozenset()) -> Mission | None:
    """The typed mission; semantic problems are appended to ``problems`` (None if any).

    ``broken`` names the items (``vehicles[1]``, ``obstacles[0]``) the schema already refused:
    they are checked no further, so one wrong value does not hide the next item's problems."""
    schema = mission_schema()["$defs"]
    planner = _planner(copy.deepcopy(data.get("planner", {})), schema["planner"]["properties"])
    safety_raw, sdef = data.get("safety", {}), schema["safety"]["properties"]
    safety = SafetySettings(**{k: float(_opt(safety_raw, sdef, k)) for k in sdef})
    coord_raw, cdef = data.get("coordination", {}), schema["coordination"]["properties"]
    kind = {f.name: type(f.default) for f in fields(CoordinationSettings)}  # bool, float, Forecast
    coordination = CoordinationSettings(**{k: kind[k](_opt(coord_raw, cdef, k)) for k in cdef})
    report = _Problems(source, root, problems)
    world = _world(data, planner.inflation_ratio, report, broken)
    nx, ny = grid_shape(world.geofence.bounds, planner.grid_resolution_m)
    if nx * ny > MAX_GRID_CELLS:
        report.add(["planner", "grid_resolution_m"],
                   f"a {planner.grid_resolution_m:g} m grid over the geofence is {nx} x {ny} cells, more than the "
                   f"limit of {MAX_GRID_CELLS}; use a coarser grid_resolution_m")
    stations = _stations(data, world, report)
    vehicles = _vehicles(data, stations, schema["vehicle"]["properties"], report, broken)
    for v in vehicles:
        if planner.min_speed_m_s > v.speed_m_s:
            report.add(["planner", "min_speed_m_s"],
                       f"{planner.min_speed_m_s:g} is above vehicle {v.name!r}'s speed_m_s ({v.speed_m_s:g})")
    _check_shared_goals(vehicles, safety, report)
    named = {v.get("name") for v in data["vehicles"] if isinstance(v, dict)}  # a broken vehicle is no unknown name
    pairs = None if {"vehicles", "sightline"} & broken else assigned_pairs(data.get("sightline"), vehicles, named,
                                                                        report.add)
    if problems:
        return None
    return Mission(name=data.get("name", Path(source).stem), source=source,
                   description=data.get("description", ""), origin=origin, world=world,
                   stations=stations, vehicles=tuple(vehicles), planner=planner, safety=safety,
                   plant=Plant(data.get("plant", schema_default("plant"))),
                   coordination=coordination, assigned_pairs=pairs)


def _planner(planner_raw: dict, pdef: dict) -> PlannerSettings:
    weights = planner_raw.get("weights", {})
    wdef = pdef["weights"]["properties"]
    return PlannerSettings(
        variant=_opt(planner_raw, pdef, "variant"),
        grid_resolution_m=float(_opt(planner_raw, pdef, "grid_resolution_m")),
        yaw_rate_samples=int(_opt(planner_raw, pdef, "yaw_rate_samples")),
        dt_s=float(_opt(planner_raw, pdef, "dt_s")),
        prediction_time_s=(None if _opt(planner_raw, pdef, "prediction_time_s") is None
                           else float(planner_raw["prediction_time_s"])),
        weight_heading=float(_opt(weights, wdef, "heading")),
        weight_distance=float(_opt(weights, wdef, "distance")),
        weight_sightline=float(_opt(weights, wdef, "sightline")),
        inflation_ratio=float(_opt(planner_raw, pdef, "inflation_ratio")),
        acceptance_radius_m=float(_opt(planner_raw, pdef, "acceptance_radius_m")),
        sightline_cap_m=float(_opt(planner_raw, pdef, "sightline_cap_m")),
        replan_after_s=float(_opt(planner_raw, pdef, "replan_after_s")),
        speed_samples=(None if _opt(planner_raw, pdef, "speed_samples") is None else int(planner_raw["speed_samples"])),
        min_speed_m_s=float(_opt(planner_raw, pdef, "min_speed_m_s")),
        weight_speed=float(_opt(weights, wdef, "speed")),
        sightline_critic=(None if _opt(planner_raw, pdef, "sightline_critic") is None
                          else SightlineCritic(planner_raw["sightline_critic"])),
        normalisation=(None if _opt(planner_raw, pdef, "normalisation") is None
                       else Normalisation(planner_raw["normalisation"])),
        final_approach=(None if _opt(planner_raw, pdef, "final_approach") is None
                        else bool(planner_raw["final_approach"])),
    )


def _world(data: dict, inflation_ratio: float, report: _Problems, broken: set[str]) -> World:
    area = data["area"]
    adef = mission_schema()["properties"]["area"]["properties"]
    x0, y0, x1, y1 = (float(area[k]) for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m"))
    if x1 <= x0:
        report.add(["area", "x_max_m"], f"must be greater than x_min_m ({x0})")
    if y1 <= y0:
        report.add(["area", "y_max_m"], f"must be greater than y_min_m ({y0})")
    margin = float(_opt(area, adef, "geofence_margin_m"))
    obstacles: list[Obstacle] = []
    seen_ids: set[str] = set()
    for i, o in enumerate(data.get("obstacles", [])):
        oid = o.get("id", f"obstacle{i}")
        if oid in seen_ids:
            report.add(["obstacles", i, "id"], f"duplicate obstacle id {oid!r}")
        seen_ids.add(oid)
        if f"obstacles[{i}]" in broken or "obstacles" in broken:  # the item, or the list (over its limit)
            continue
        obstacle = _obstacle(o, oid, i, inflation_ratio, report)
        if obstacle is not None:
            obstacles.append(obstacle)
    return World(x0, y0, x1, y1, margin, tuple(obstacles))


def _obstacle(o: dict, oid: str, i: int, inflation_ratio: float, report: _Problems) -> Obstacle | None:
    kind = o["shape"]
    if kind == "polygon":
        poly_vertices = [tuple(map(float, p)) for p in o["vertices"]]
        from shapely.geometry import Polygon
        if not Polygon(poly_vertices).is_valid or Polygon(poly_vertices).area <= 0:
            report.add(["obstacles", i, "vertices"], "polygon is self-intersecting or has no area")
            return None
    obstacle = make_obstacle(
        oid, kind,
        center=tuple(map(float, o["center"])) if "center" in o else None,
        radius_m=o.get("radius_m"), width_m=o.get("width_m"), height_m=o.get("height_m"),
        circumradius_m=o.get("circumradius_m"),
        vertices=[tuple(map(float, p)) for p in o["vertices"]] if "vertices" in o else None,
        rotation_deg=float(o.get("rotation_deg", 0.0)),
        inflation_ratio=inflation_ratio,
    )
    motion = _motion(o.get("motion"), obstacle.center)
    return Obstacle(id=obstacle.id, kind=obstacle.kind, center=obstacle.center, size_m=obstacle.size_m,
                    footprint=obstacle.footprint, margin_m=obstacle.margin_m, motion=motion)


def _stations(data: dict, world: World, report: _Problems) -> dict[str, tuple[float, float]]:
    stations = {name: (float(p[0]), float(p[1])) for name, p in data["stations"].items()}
    for name, (x, y) in stations.items():
        path = ["stations", name]
        if not (world.x_min_m <= x <= world.x_max_m and world.y_min_m <= y <= world.y_max_m):
            report.add(path, f"station ({x:g}, {y:g}) lies outside the area")
        for o in world.static_obstacles:
            if o.inflated.intersects(Point(x, y)):
                report.add(path, f"station ({x:g}, {y:g}) lies inside obstacle {o.id!r} "
                                 f"(inflated by {o.margin_m:g} m)")
    return stations


def _vehicles(data: dict, stations: dict[str, tuple[float, float]], vdef: dict, report: _Problems,
              broken: set[str]) -> list[VehicleSpec]:
    vehicles: list[VehicleSpec] = []
    names: set[str] = set()
    sysids: set[int] = set()
    for i, v in enumerate(data["vehicles"]):
        base = ["vehicles", i]
        if v["name"] in names:
            report.add(base + ["name"], f"duplicate vehicle name {v['name']!r}")
        names.add(v["name"])
        sysid = int(v.get("system_id", i + 1))
        if sysid in sysids:
            report.add(base + ["system_id"], f"duplicate system id {sysid}")
        sysids.add(sysid)
        unknown = [key for key in ("start", "goal") if v[key] not in stations]
        for key in unknown:
            report.add(base + [key], f"unknown station {v[key]!r}; stations are {', '.join(stations)}")
        if v["start"] == v["goal"]:
            report.add(base + ["goal"], "goal is the same station as start")
        if unknown or f"vehicles[{i}]" in broken:
            continue
        vehicles.append(VehicleSpec(
            name=v["name"], index=i, system_id=sysid,
            connection=v.get("connection", f"udpin://0.0.0.0:{API_PORT_BASE + i}"),
            start=v["start"], goal=v["goal"],
            start_enu_m=stations[v["start"]], goal_enu_m=stations[v["goal"]],
            speed_m_s=float(_opt(v, vdef, "speed_m_s")),
            turn_radius_m=float(_opt(v, vdef, "turn_radius_m")),
            max_accel_m_s2=float(_opt(v, vdef, "max_accel_m_s2")),
            cruise_alt_m=float(_opt(v, vdef, "cruise_alt_m")),
            initial_heading_deg=float(_opt(v, vdef, "initial_heading_deg")),
            priority=int(v.get("priority", i)),
            battery_pct=None if _opt(v, vdef, "battery_pct") is None else float(_opt(v, vdef, "battery_pct")),
            spawn_heading=SpawnHeading(_opt(v, vdef, "spawn_heading")),
        ))
    return vehicles


def _check_shared_goals(vehicles: list[VehicleSpec], safety: SafetySettings, report: _Problems) -> None:
    """Two vehicles cannot both arrive at one station when the arrival disc is narrower than the
    separation they must keep: refuse that before anything flies (a wider disc is only warned
    about, by ``companion validate``)."""
    if 2.0 * safety.arrival_radius_m >= safety.min_separation_m:
        return
    first: dict[str, VehicleSpec] = {}
    for v in vehicles:
        if v.goal in first:
            report.add(["vehicles", v.index, "goal"],
                       f"station {v.goal!r} is already the goal of vehicle {first[v.goal].name!r}: both "
                       f"cannot be within the arrival radius ({safety.arrival_radius_m:g} m) and "
                       f"{safety.min_separation_m:g} m apart; give each vehicle its own goal")
        else:
            first[v.goal] = v
