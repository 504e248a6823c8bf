"""Mission files: the one loader, the published JSON Schema, and the typed objects they become.

Validation happens here and only here (SPEC §5). A bad file raises :class:`MissionError`, whose
message names the file, the line and the field path; everything downstream receives frozen,
already-valid objects.

    MissionError
        raised for: unreadable file, YAML syntax, schema violation (unknown key, wrong type,
        out of range), dangling station names, duplicate names or ids, a station outside the
        area or inside an inflated obstacle. An unreachable goal is found by the planner and
        reported through :func:`mission_error` with the vehicle's field path.
"""

from __future__ import annotations

import copy
import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Literal, get_args

import jsonschema
import yaml
from shapely.geometry import Point

from uav_model.frames import GeoOrigin
from uav_model.mission_points import latlon_slips, localise
from uav_model.plant import Plant
from uav_model.world import Obstacle, Orbit, Patrol, Shuttle, Static, World, make_obstacle

Variant = Literal["astar-bdwa", "astar-bdwa-nosparse", "bdwa", "dwa"]
VARIANTS: tuple[str, ...] = get_args(Variant)

DEFAULT_ORIGIN = GeoOrigin(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)  # PX4 SITL home
API_PORT_BASE = 14540  # PX4 SITL: vehicle i talks to the companion on 14540 + i


class MissionError(ValueError):
    """A mission file that cannot be flown. ``str()`` is one line: ``file:line: path: reason``."""

    def __init__(self, source: str, field_path: str, reason: str, line: int | None = None):
        self.source = source
        self.field_path = field_path
        self.reason = reason
        self.line = line
        self.problems: tuple[MissionError, ...] = (self,)
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {field_path}: {reason}" if field_path else f"{where}: {reason}")

    @classmethod
    def of(cls, problems: list["MissionError"]) -> "MissionError":
        """One error for several problems, in file order: ``str()`` is one line per problem."""
        ordered = sorted(problems, key=lambda e: (e.line is None, e.line or 0, e.field_path))
        first = ordered[0]
        combined = cls(first.source, first.field_path, first.reason, first.line)
        combined.problems = tuple(ordered)
        combined.args = ("\n".join(str(e) for e in ordered),)
        return combined

    def __reduce__(self):
        return (_rebuild_error, (self.source, self.field_path, self.reason, self.line,
                                 tuple((e.field_path, e.reason, e.line) for e in self.problems)))


def _rebuild_error(source: str, field_path: str, reason: str, line: int | None,
                   problems: tuple[tuple[str, str, int | None], ...]) -> MissionError:
    if len(problems) <= 1:
        return MissionError(source, field_path, reason, line)
    return MissionError.of([MissionError(source, f, r, ln) for f, r, ln in problems])


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    name: str
    index: int  # position in the file; sets the default system id and port
    system_id: int
    connection: str
    start: str
    goal: str
    start_enu_m: tuple[float, float]
    goal_enu_m: tuple[float, float]
    speed_m_s: float
    turn_radius_m: float
    max_accel_m_s2: float
    cruise_alt_m: float
    initial_heading_deg: float
    priority: int
    battery_pct: float

    @property
    def max_yaw_rate_rad_s(self) -> float:
        """The turn-radius limit as a yaw rate: |omega| <= v / r."""
        return self.speed_m_s / self.turn_radius_m

    @property
    def initial_heading_rad(self) -> float:
        return math.radians(self.initial_heading_deg)


@dataclass(frozen=True, slots=True)
class PlannerSettings:
    variant: str
    grid_resolution_m: float
    yaw_rate_samples: int
    dt_s: float
    prediction_time_s: float | None
    weight_heading: float
    weight_distance: float
    weight_sightline: float
    inflation_ratio: float
    acceptance_radius_m: float
    sightline_cap_m: float
    replan_after_s: float  # 0: never re-plan (see VehiclePlanner)

    def prediction_time_for(self, vehicle: VehicleSpec) -> float:
        """The paper's p = ceil(2*pi / ((v/r) * 2)) + 1 seconds, unless the mission fixes it."""
        if self.prediction_time_s is not None:
            return self.prediction_time_s
        return math.ceil(2.0 * math.pi / (vehicle.max_yaw_rate_rad_s * 2.0)) + 1.0


@dataclass(frozen=True, slots=True)
class SafetySettings:
    min_separation_m: float
    arrival_radius_m: float
    time_limit_s: float
    telemetry_timeout_s: float


@dataclass(frozen=True, slots=True)
class CoordinationSettings:
    """Coordinated timing (docs/design.md): who may wait, and the space-time plan's step."""

    hold_s_max: float = 0.0  # the first vehicle in priority may hold at its station this long (paper: 0)
    step_s: float = 5.0      # nominal time step of the space-time plan


@dataclass(frozen=True)
class Mission:
    name: str
    source: str
    description: str
    origin: GeoOrigin
    world: World
    stations: dict[str, tuple[float, float]]
    vehicles: tuple[VehicleSpec, ...]  # in file order
    planner: PlannerSettings
    safety: SafetySettings
    plant: Plant = Plant.MULTICOPTER  # the dynamics the stub and the headless runner fly
    coordination: CoordinationSettings = CoordinationSettings()

    @property
    def by_priority(self) -> tuple[VehicleSpec, ...]:
        """Vehicles in planning order: lowest priority value first, ties in file order."""
        return tuple(sorted(self.vehicles, key=lambda v: (v.priority, v.index)))

    def vehicle(self, name: str) -> VehicleSpec:
        for v in self.vehicles:
            if v.name == name:
                return v
        raise KeyError(name)

    def with_variant(self, variant: str) -> "Mission":
        """The same mission flown with another planner variant."""
        if variant not in VARIANTS:
            raise MissionError(self.source, "planner.variant", f"unknown variant {variant!r}; one of {', '.join(VARIANTS)}")
        from dataclasses import replace
        return replace(self, planner=replace(self.planner, variant=variant))


@lru_cache(maxsize=1)
def mission_schema() -> dict[str, Any]:
    """The published JSON Schema for mission files (``companion schema`` prints it)."""
    text = resources.files("uav_model").joinpath("schema/mission.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


class _LineLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (silently dropping one is lost data)."""


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, yaml.Node] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen[key] = key_node
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _line_of(root: yaml.Node | None, path: list[Any]) -> int | None:
    """1-based line of the deepest YAML node that the path reaches."""
    node = root
    line = None if node is None else node.start_mark.line + 1
    for part in path:
        if isinstance(node, yaml.MappingNode):
            nxt = None
            for k, v in node.value:
                if k.value == str(part):
                    nxt = v
                    line = k.start_mark.line + 1
                    break
            node = nxt
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) and part < len(node.value):
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            break
        if node is None:
            break
    return line


def _dotted(path: list[Any] | tuple[Any, ...]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _schema_reason(err: jsonschema.ValidationError) -> tuple[list[Any], str]:
    """Turn a jsonschema error into (field path, short reason) that a user can act on."""
    path = list(err.absolute_path)
    if err.validator == "additionalProperties":
        allowed = sorted(err.schema.get("properties", {}))
        extra = [k for k in err.instance if k not in err.schema.get("properties", {})] if isinstance(err.instance, dict) else []
        if extra:
            hint = f"; allowed: {', '.join(allowed)}" if allowed else ""
            return path + [extra[0]], f"unknown key {extra[0]!r}{hint}"
    if err.validator == "required":
        return path, err.message.replace("is a required property", "is required")
    if err.validator == "type":
        return path, f"expected {err.validator_value}, got {type(err.instance).__name__} {err.instance!r}"
    if err.validator == "enum":
        return path, f"{err.instance!r} is not one of {', '.join(map(str, err.validator_value))}"
    return path, err.message


def mission_error(mission_or_source: Mission | str, field_path: str, reason: str,
                  root: yaml.Node | None = None) -> MissionError:
    """A MissionError for a semantic problem found after loading (e.g. an unreachable goal)."""
    source = mission_or_source.source if isinstance(mission_or_source, Mission) else mission_or_source
    line = None
    if root is None:
        try:
            root = yaml.compose(Path(source).read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            root = None
    if root is not None:
        parts: list[Any] = []
        for token in field_path.replace("[", ".[").split("."):
            if not token:
                continue
            parts.append(int(token[1:-1]) if token.startswith("[") else token)
        line = _line_of(root, parts)
    return MissionError(source, field_path, reason, line)


def load_mission(path: str | Path) -> Mission:
    """Read, validate and type a mission file. Raises MissionError, never anything else."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MissionError(source, "", "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionError(source, "", f"cannot read file: {exc}") from None
    return parse_mission(text, source)


def parse_mission(text: str, source: str = "<mission>") -> Mission:
    """Validate and type mission YAML text; ``source`` names it in errors."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.load(text, Loader=_LineLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise MissionError(source, "", f"YAML syntax: {problem}", line) from None
    if not isinstance(data, dict):
        raise MissionError(source, "", "a mission file must be a YAML mapping", _line_of(root, []))
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
    validator = jsonschema.Draft202012Validator(mission_schema())
    problems: dict[str, MissionError] = {}
    for err in validator.iter_errors(data):
        best = err
        # Descend into if/then and oneOf branches so the message names the real field.
        while best.context:
            best = jsonschema.exceptions.best_match(best.context)
        path, reason = _schema_reason(best)
        problems.setdefault(_dotted(path), MissionError(source, _dotted(path), reason, _line_of(root, path)))
    return list(problems.values())


def _validated(data: dict[str, Any], source: str, root: yaml.Node | None) -> Mission:
    """Check the whole document and report every problem at once (``MissionError.problems``)."""
    problems = _schema_problems(data, source, root)
    origin = _origin(data.get("origin")) if not any(p.field_path.startswith("origin") for p in problems) else DEFAULT_ORIGIN
    problems += [_fail(source, root, path, reason) for path, reason in latlon_slips(data, origin)]
    found: list[MissionError] = []
    mission = None
    try:
        broken = {re.match(r"^[a-z_]+(\[\d+\])?", p.field_path).group(0) for p in problems if p.field_path}
        mission = _build(localise(data, origin), source, root, origin, found, broken)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError):
        if not problems and not found:  # a valid document must build: our bug, not the file's
            raise
    problems += found
    if problems:
        raise MissionError.of(problems)
    assert mission is not None
    return mission


def _fail(source: str, root: yaml.Node | None, path: list[Any], reason: str) -> MissionError:
    return MissionError(source, _dotted(path), reason, _line_of(root, path))


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


def _build(data: dict, source: str, root: yaml.Node | None, origin: GeoOrigin,
           problems: list[MissionError], broken: set[str] = frozenset()) -> Mission | None:
    """The typed mission; semantic problems are appended to ``problems`` (None if any).

    ``broken`` names the items (``vehicles[1]``, ``obstacles[0]``) the schema already refused:
    they are checked no further, so one wrong value does not hide the next item's problems."""
    schema = mission_schema()["$defs"]
    planner_raw = copy.deepcopy(data.get("planner", {}))
    weights = planner_raw.get("weights", {})
    pdef = schema["planner"]["properties"]
    wdef = pdef["weights"]["properties"]
    sdef = schema["safety"]["properties"]
    vdef = schema["vehicle"]["properties"]

    def opt(raw: dict, defs: dict, key: str):
        return raw.get(key, defs[key].get("default"))

    planner = PlannerSettings(
        variant=opt(planner_raw, pdef, "variant"),
        grid_resolution_m=float(opt(planner_raw, pdef, "grid_resolution_m")),
        yaw_rate_samples=int(opt(planner_raw, pdef, "yaw_rate_samples")),
        dt_s=float(opt(planner_raw, pdef, "dt_s")),
        prediction_time_s=(None if opt(planner_raw, pdef, "prediction_time_s") is None
                           else float(planner_raw["prediction_time_s"])),
        weight_heading=float(opt(weights, wdef, "heading")),
        weight_distance=float(opt(weights, wdef, "distance")),
        weight_sightline=float(opt(weights, wdef, "sightline")),
        inflation_ratio=float(opt(planner_raw, pdef, "inflation_ratio")),
        acceptance_radius_m=float(opt(planner_raw, pdef, "acceptance_radius_m")),
        sightline_cap_m=float(opt(planner_raw, pdef, "sightline_cap_m")),
        replan_after_s=float(opt(planner_raw, pdef, "replan_after_s")),
    )
    safety_raw = data.get("safety", {})
    safety = SafetySettings(**{k: float(opt(safety_raw, sdef, k)) for k in sdef})
    coord_raw = data.get("coordination", {})
    cdef = schema["coordination"]["properties"]
    coordination = CoordinationSettings(**{k: float(opt(coord_raw, cdef, k)) for k in cdef})

    area = data["area"]
    adef = mission_schema()["properties"]["area"]["properties"]
    x0, y0, x1, y1 = (float(area[k]) for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m"))
    if x1 <= x0:
        problems.append(_fail(source, root, ["area", "x_max_m"], f"must be greater than x_min_m ({x0})"))
    if y1 <= y0:
        problems.append(_fail(source, root, ["area", "y_max_m"], f"must be greater than y_min_m ({y0})"))
    margin = float(opt(area, adef, "geofence_margin_m"))

    obstacles: list[Obstacle] = []
    seen_ids: set[str] = set()
    for i, o in enumerate(data.get("obstacles", [])):
        oid = o.get("id", f"obstacle{i}")
        if oid in seen_ids:
            problems.append(_fail(source, root, ["obstacles", i, "id"], f"duplicate obstacle id {oid!r}"))
        seen_ids.add(oid)
        kind = o["shape"]
        if f"obstacles[{i}]" in broken:
            continue
        if kind == "polygon":
            poly_vertices = [tuple(map(float, p)) for p in o["vertices"]]
            from shapely.geometry import Polygon
            if not Polygon(poly_vertices).is_valid or Polygon(poly_vertices).area <= 0:
                problems.append(_fail(source, root, ["obstacles", i, "vertices"],
                                      "polygon is self-intersecting or has no area"))
                continue
        obstacle = make_obstacle(
            oid, kind,
            center=tuple(map(float, o["center"])) if "center" in o else None,
            radius_m=o.get("radius_m"), width_m=o.get("width_m"), height_m=o.get("height_m"),
            circumradius_m=o.get("circumradius_m"),
            vertices=[tuple(map(float, p)) for p in o["vertices"]] if "vertices" in o else None,
            rotation_deg=float(o.get("rotation_deg", 0.0)),
            inflation_ratio=planner.inflation_ratio,
        )
        motion = _motion(o.get("motion"), obstacle.center)
        obstacles.append(Obstacle(id=obstacle.id, kind=obstacle.kind, center=obstacle.center,
                                  size_m=obstacle.size_m, footprint=obstacle.footprint,
                                  margin_m=obstacle.margin_m, motion=motion))
    world = World(x0, y0, x1, y1, margin, tuple(obstacles))

    stations = {name: (float(p[0]), float(p[1])) for name, p in data["stations"].items()}
    for name, (x, y) in stations.items():
        path = ["stations", name]
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            problems.append(_fail(source, root, path, f"station ({x:g}, {y:g}) lies outside the area"))
        for o in world.static_obstacles:
            if o.inflated.intersects(Point(x, y)):
                problems.append(_fail(source, root, path,
                                      f"station ({x:g}, {y:g}) lies inside obstacle {o.id!r} "
                                      f"(inflated by {o.margin_m:g} m)"))

    vehicles: list[VehicleSpec] = []
    names: set[str] = set()
    sysids: set[int] = set()
    for i, v in enumerate(data["vehicles"]):
        base = ["vehicles", i]
        if v["name"] in names:
            problems.append(_fail(source, root, base + ["name"], f"duplicate vehicle name {v['name']!r}"))
        names.add(v["name"])
        sysid = int(v.get("system_id", i + 1))
        if sysid in sysids:
            problems.append(_fail(source, root, base + ["system_id"], f"duplicate system id {sysid}"))
        sysids.add(sysid)
        unknown = [key for key in ("start", "goal") if v[key] not in stations]
        for key in unknown:
            problems.append(_fail(source, root, base + [key],
                                  f"unknown station {v[key]!r}; stations are {', '.join(stations)}"))
        if v["start"] == v["goal"]:
            problems.append(_fail(source, root, base + ["goal"], "goal is the same station as start"))
        if unknown or f"vehicles[{i}]" in broken:
            continue
        vehicles.append(VehicleSpec(
            name=v["name"], index=i, system_id=sysid,
            connection=v.get("connection", f"udpin://0.0.0.0:{API_PORT_BASE + i}"),
            start=v["start"], goal=v["goal"],
            start_enu_m=stations[v["start"]], goal_enu_m=stations[v["goal"]],
            speed_m_s=float(opt(v, vdef, "speed_m_s")),
            turn_radius_m=float(opt(v, vdef, "turn_radius_m")),
            max_accel_m_s2=float(opt(v, vdef, "max_accel_m_s2")),
            cruise_alt_m=float(opt(v, vdef, "cruise_alt_m")),
            initial_heading_deg=float(opt(v, vdef, "initial_heading_deg")),
            priority=int(v.get("priority", i)),
            battery_pct=float(opt(v, vdef, "battery_pct")),
        ))

    _check_shared_goals(vehicles, safety, source, root, problems)
    if problems:
        return None
    return Mission(name=data.get("name", Path(source).stem), source=source,
                   description=data.get("description", ""), origin=origin, world=world,
                   stations=stations, vehicles=tuple(vehicles), planner=planner, safety=safety,
                   plant=Plant(data.get("plant", mission_schema()["properties"]["plant"]["default"])),
                   coordination=coordination)


def shared_goals(mission: Mission) -> dict[str, list[str]]:
    """Goal stations that more than one vehicle flies to, with those vehicles' names."""
    by_goal: dict[str, list[str]] = {}
    for v in mission.vehicles:
        by_goal.setdefault(v.goal, []).append(v.name)
    return {goal: names for goal, names in by_goal.items() if len(names) > 1}


def _check_shared_goals(vehicles: list[VehicleSpec], safety: SafetySettings, source: str,
                        root: yaml.Node | None, problems: list[MissionError]) -> None:
    """Two vehicles cannot both arrive at one station when the arrival disc is narrower than the
    separation they must keep: refuse that before anything flies (a wider disc is only warned
    about, by ``companion validate``)."""
    if 2.0 * safety.arrival_radius_m >= safety.min_separation_m:
        return
    first: dict[str, VehicleSpec] = {}
    for v in vehicles:
        if v.goal in first:
            problems.append(_fail(source, root, ["vehicles", v.index, "goal"],
                                  f"station {v.goal!r} is already the goal of vehicle {first[v.goal].name!r}: both "
                                  f"cannot be within the arrival radius ({safety.arrival_radius_m:g} m) and "
                                  f"{safety.min_separation_m:g} m apart; give each vehicle its own goal"))
        else:
            first[v.goal] = v
