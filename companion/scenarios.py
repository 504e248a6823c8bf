"""Seeded random complex scenarios (SPEC §3, the paper's section VI.C).

Scenario ``index`` of ``seed`` is a mission document (the same dict a mission YAML file holds),
identical on every machine: it draws only from its own ``random.Random`` seeded by integers, and
rounds every number it writes. A drawn scenario is redrawn (from the same stream) when a station
lies within ``station_clearance_m`` of an inflated obstacle, static or anywhere along a moving
obstacle's path, or when no static route exists for the vehicles (``plan_routes`` fails).

    doc = generate(2026, 7)                    # dict, ready for yaml
    mission = generate_mission(2026, 7)        # validated Mission
    scenario = generate_scenario(2026, 7)      # doc + mission + the routes the check planned
    write_mission_yaml(doc, "s2026_i7.yaml")   # replays with `companion simulate`
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from uav_model.mission import Mission, mission_from_data
from uav_model.plant import Plant
from companion.planning.errors import NoPath
from companion.planning.routes import Route, plan_routes
from uav_model.world import Obstacle, Shuttle

REFERENCE_SIDE_M = 4500.0 / math.sqrt(2.0)
MAX_VEHICLES = 32  # the mission schema's maxItems
SIGHT_PAIR_RULES = ("opposite",)  # ScenarioConfig.sight_pairs (None: no sightline section)


class ScenarioError(ValueError):
    """A scenario config that cannot be used, or a seed for which no valid scenario was drawn."""


@dataclass(frozen=True)
class ScenarioConfig:
    """SPEC §3's suggested defaults. Ranges are (low, high) for a uniform draw."""

    side_m: float = round(REFERENCE_SIDE_M, 2)
    static_count: int = 5
    static_shapes: tuple[str, ...] = ("circle", "rectangle", "triangle")  # rectangle drawn square
    static_circumradius_m: tuple[float, float] = (150.0, 450.0)
    central_fraction: float = 0.6
    moving_count: int = 2
    moving_radius_m: tuple[float, float] = (80.0, 150.0)
    moving_path_m: tuple[float, float] = (600.0, 1500.0)
    moving_speed_m_s: tuple[float, float] = (2.0, 5.0)
    station_clearance_m: float = 300.0
    inflation_ratio: float = 0.2
    max_redraws: int = 200
    time_limit_s: float | None = None  # None: the mission default (SPEC §2: 2500 s)
    plant: str = Plant.MULTICOPTER.value  # unicycle: the paper's ideal vehicle (its Table IV)
    vehicles: int = 2  # around the square's perimeter, each flying across it (see fleet_layout)
    # Assigned sight-line pairs written as the mission's sightline.pairs; None: no section, the
    # paper's pair. "opposite": each vehicle with the one starting opposite it (opposite_pairs).
    sight_pairs: str | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, list):  # from YAML
                object.__setattr__(self, f.name, tuple(value))
        bad = [s for s in self.static_shapes if s not in ("circle", "rectangle", "triangle")]
        if bad or not self.static_shapes:
            raise ScenarioError(f"static_shapes: use circle, rectangle or triangle (got {list(self.static_shapes)})")
        for name in ("static_circumradius_m", "moving_radius_m", "moving_path_m", "moving_speed_m_s"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ScenarioError(f"{name}: need 0 < low <= high (got [{lo}, {hi}])")
        if not 0 < self.central_fraction <= 1:
            raise ScenarioError(f"central_fraction: must be in (0, 1] (got {self.central_fraction})")
        if self.side_m <= 0 or self.static_count < 0 or self.moving_count < 0 or self.max_redraws < 1:
            raise ScenarioError("side_m, static_count, moving_count and max_redraws must be positive")
        if self.time_limit_s is not None and not self.time_limit_s > 0:
            raise ScenarioError(f"time_limit_s: must be positive (got {self.time_limit_s})")
        if self.plant not in {p.value for p in Plant}:
            raise ScenarioError(f"plant: use {' or '.join(p.value for p in Plant)} (got {self.plant!r})")
        if not 2 <= self.vehicles <= MAX_VEHICLES:
            raise ScenarioError(f"vehicles: use 2 to {MAX_VEHICLES} (got {self.vehicles})")
        if self.sight_pairs is not None and self.sight_pairs not in SIGHT_PAIR_RULES:
            raise ScenarioError(f"sight_pairs: use {' or '.join(SIGHT_PAIR_RULES)} (got {self.sight_pairs!r})")
        if self.sight_pairs == "opposite" and self.vehicles % 2:
            raise ScenarioError(f"sight_pairs: opposite pairs each vehicle with the one starting opposite it, "
                                f"which needs an even number of vehicles (got {self.vehicles})")
        if self.moving_path_m[1] >= self.side_m:
            raise ScenarioError(f"moving_path_m: a path must fit in the {self.side_m:g} m square")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "ScenarioConfig":
        """A config from a YAML mapping; unknown keys are refused by name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ScenarioError(f"unknown scenario key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        try:
            return cls(**dict(data))
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ScenarioError):
                raise
            raise ScenarioError(f"bad scenario config: {exc}") from None

    @property
    def central_box_m(self) -> tuple[float, float]:
        """(low, high) of both coordinates of the central ``central_fraction`` of the square."""
        lo = self.side_m * (1.0 - self.central_fraction) / 2.0
        return lo, self.side_m - lo


@dataclass(frozen=True)
class Scenario:
    """One generated scenario: its document, the validated mission, and the routes that proved a
    static route exists (reusable by the A* variants: routes do not depend on the variant)."""

    seed: int
    index: int
    doc: dict[str, Any]
    mission: Mission
    routes: dict[str, Route]
    draws: int  # how many draws it took (1 = the first was valid)


def _r(x: float) -> float:
    return round(float(x), 2)


def _rng(seed: int, index: int) -> random.Random:
    # Integer seeding is specified by CPython to be platform independent.
    return random.Random(seed * 1_000_003 + index)


def _draw(rng: random.Random, cfg: ScenarioConfig, seed: int, index: int) -> dict[str, Any] | None:
    """One draw; None when a moving path could not be placed inside the square (redraw)."""
    side = cfg.side_m
    lo, hi = cfg.central_box_m
    obstacles: list[dict[str, Any]] = []
    for k in range(cfg.static_count):
        shape = rng.choice(cfg.static_shapes)
        rc = rng.uniform(*cfg.static_circumradius_m)
        cx, cy = rng.uniform(lo, hi), rng.uniform(lo, hi)
        rot = rng.uniform(0.0, 360.0)
        ob: dict[str, Any] = {"id": f"s{k}", "shape": shape, "center": [_r(cx), _r(cy)]}
        if shape == "circle":
            ob["radius_m"] = _r(rc)
        elif shape == "rectangle":  # a square of circumradius rc
            ob["width_m"] = ob["height_m"] = _r(rc * math.sqrt(2.0))
            ob["rotation_deg"] = _r(rot)
        else:
            ob["circumradius_m"] = _r(rc)
            ob["rotation_deg"] = _r(rot)
        obstacles.append(ob)
    for k in range(cfg.moving_count):
        radius = rng.uniform(*cfg.moving_radius_m)
        length = rng.uniform(*cfg.moving_path_m)
        speed = rng.uniform(*cfg.moving_speed_m_s)
        for _ in range(100):  # the far end must stay in the square too
            cx, cy = rng.uniform(lo, hi), rng.uniform(lo, hi)
            heading = rng.uniform(0.0, 2.0 * math.pi)
            tx, ty = cx + length * math.cos(heading), cy + length * math.sin(heading)
            if 0.0 <= tx <= side and 0.0 <= ty <= side:
                break
        else:
            return None
        obstacles.append({"id": f"m{k}", "shape": "circle", "center": [_r(cx), _r(cy)],
                          "radius_m": _r(radius),
                          "motion": {"type": "shuttle", "to": [_r(tx), _r(ty)], "speed_m_s": _r(speed)}})
    fleet = fleet_layout(side, cfg.vehicles)
    doc = {
        "name": f"random_s{seed}_i{index}",
        "description": f"Seeded random complex scenario (seed {seed}, index {index}; SPEC §3)",
        "plant": cfg.plant,
        "area": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": side, "y_max_m": side, "geofence_margin_m": 200.0},
        "stations": fleet["stations"],
        "obstacles": obstacles,
        "vehicles": fleet["vehicles"],
        "planner": {"inflation_ratio": cfg.inflation_ratio},
    }
    if cfg.time_limit_s is not None:
        doc["safety"] = {"time_limit_s": cfg.time_limit_s}
    if cfg.sight_pairs is not None:
        doc["sightline"] = {"pairs": opposite_pairs(cfg.vehicles)}
    return doc


def _perimeter_point(side: float, d: float) -> tuple[float, float]:
    """The point ``d`` metres along the square's perimeter from (0, 0), counter-clockwise."""
    d %= 4.0 * side
    if d <= side:
        return d, 0.0
    if d <= 2.0 * side:
        return side, d - side
    if d <= 3.0 * side:
        return 3.0 * side - d, side
    return 0.0, 4.0 * side - d


def fleet_layout(side: float, count: int) -> dict[str, Any]:
    """Stations and vehicles of an N-vehicle scenario: vehicle i starts at the perimeter point
    i/N of the way round from (0, 0) and flies to the point opposite it through the centre, so
    every route crosses the middle and every goal is distinct. Priority is the order (vehicle
    ``a`` first); the first keeps a full battery, as in the paper's two-vehicle case. Two
    vehicles give the paper's A (0, 0) <-> B (side, side) exactly."""
    starts = [_perimeter_point(side, i * 4.0 * side / count) for i in range(count)]
    goals = [(side - x, side - y) for x, y in starts]
    points: list[tuple[float, float]] = []
    for p in [*starts, *goals]:
        p = (_r(p[0]), _r(p[1]))
        if p not in points:
            points.append(p)
    # stations named in perimeter order, A at (0, 0)
    along = {p: math.atan2(p[1] - side / 2.0, p[0] - side / 2.0) for p in points}
    first = along[points[0]]
    points.sort(key=lambda p: (along[p] - first) % (2.0 * math.pi))
    name = {p: _label("A", k) for k, p in enumerate(points)}
    vehicles = []
    for i, (start, goal) in enumerate(zip(starts, goals)):
        start, goal = (_r(start[0]), _r(start[1])), (_r(goal[0]), _r(goal[1]))
        heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
        vehicles.append({"name": _label("a", i), "start": name[start], "goal": name[goal], "speed_m_s": 10.0,
                         "turn_radius_m": 30.0, "initial_heading_deg": _r(heading),
                         "battery_pct": 100.0 if i == 0 else 35.0})
    return {"stations": {name[p]: [p[0], p[1]] for p in points}, "vehicles": vehicles}


def opposite_pairs(count: int) -> list[list[str]]:
    """The head-on pairs of :func:`fleet_layout`'s ``count`` (even) vehicles: vehicle i with
    vehicle i + count/2, which starts where i's goal is, the higher in priority first
    (``[[a, c], [b, d]]`` for four; ``[[a, b]]``, the paper's pair, for two)."""
    half = count // 2
    return [[_label("a", i), _label("a", i + half)] for i in range(half)]


def _label(first: str, k: int) -> str:
    """The k-th name from letter ``first``: a..z, then a1..z1, a2...; A..Z, A1... for stations."""
    letter = chr(ord(first) + k % 26)
    return letter if k < 26 else f"{letter}{k // 26}"


def swept_region(obstacle: Obstacle) -> BaseGeometry:
    """Everything the inflated obstacle ever covers: itself, or for a moving one its whole path."""
    if not obstacle.is_moving:
        return obstacle.inflated
    motion = obstacle.motion
    if isinstance(motion, Shuttle):  # exact: the segment it shuttles along, grown by the radius
        cx, cy = obstacle.center
        path = LineString([(cx, cy), (cx + motion.delta_m[0], cy + motion.delta_m[1])])
    else:  # other motions are periodic and slow; dense samples over a long horizon suffice
        ts = np.linspace(0.0, 4000.0, 8001)
        path = LineString(np.asarray(obstacle.center) + obstacle.offset_at(ts))
    # For a polygon the inflated circumradius is a conservative stand-in for its shape.
    return path.buffer(obstacle.inflated_radius_m)


def station_clearances_m(mission: Mission) -> dict[str, float]:
    """Each station's distance to the nearest swept inflated obstacle (inf without obstacles)."""
    regions = [swept_region(o) for o in mission.world.obstacles]
    return {name: min((g.distance(Point(p)) for g in regions), default=math.inf)
            for name, p in mission.stations.items()}


def _parse(doc: dict[str, Any]) -> Mission:
    # JSON round trip: tuples become lists, as in the YAML a user would write (PyYAML, pure
    # Python, took half of the generator's time).
    return mission_from_data(json.loads(json.dumps(doc)), doc["name"])


def generate_scenario(seed: int, index: int, config: ScenarioConfig | None = None) -> Scenario:
    """Scenario ``index`` of ``seed``, with its mission and proving routes."""
    cfg = config or ScenarioConfig()
    rng = _rng(seed, index)
    for draw in range(1, cfg.max_redraws + 1):
        doc = _draw(rng, cfg, seed, index)
        if doc is None:
            continue
        mission = _parse(doc)
        if min(station_clearances_m(mission).values()) < cfg.station_clearance_m:
            continue
        try:
            routes = plan_routes(mission)
        except NoPath:
            continue
        return Scenario(seed, index, doc, mission, dict(routes), draw)
    raise ScenarioError(f"no valid scenario for seed {seed} index {index} after {cfg.max_redraws} draws")


def generate(seed: int, index: int, config: ScenarioConfig | None = None) -> dict[str, Any]:
    """The mission document of scenario ``index`` for ``seed``."""
    return generate_scenario(seed, index, config).doc


def generate_mission(seed: int, index: int, config: ScenarioConfig | None = None) -> Mission:
    return generate_scenario(seed, index, config).mission


def with_variant(doc: dict[str, Any], variant: str) -> dict[str, Any]:
    """The same document flown with ``variant`` (what a replayable failure file holds)."""
    out = dict(doc)
    out["planner"] = {**doc.get("planner", {}), "variant": variant}
    return out


def write_mission_yaml(doc: dict[str, Any], path: str | Path) -> Path:
    """Write a scenario so that ``companion simulate`` / ``companion run`` can replay it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(mission_yaml_text(doc), encoding="utf-8")
    return path


def mission_yaml_text(doc: dict[str, Any]) -> str:
    """The YAML text :func:`write_mission_yaml` writes (its description as a header comment)."""
    header = f"# {doc['description']}\n" if doc.get("description") else ""
    return header + yaml.safe_dump(doc, sort_keys=False)


def config_dict(config: ScenarioConfig) -> dict[str, Any]:
    return asdict(config)
