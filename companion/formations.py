"""Hand-shaped multi-vehicle missions: the meetings a swarm must get through, as mission documents.

Each function returns the same dict a mission YAML file holds (``companion.scenarios.write_mission_yaml``
writes it for ``companion simulate``); ``mission_from_data`` validates it.

- :func:`ring`: N vehicles evenly on a circle, each flying to the point opposite, so that every
  route meets at the centre at once (with ``hub_m``, around a round obstacle there).
- :func:`crossing_lanes`: k vehicles flying east in parallel lanes across k flying north.
- :func:`corridor`: a gap between two walls, flown both ways at once.

Vehicles are named ``v0, v1, ...`` (the ring) or by direction (``e0``, ``n0``, ``w0``); the
list order is the priority order. Every number is rounded to the centimetre.
"""

from __future__ import annotations

import math
from typing import Any


def _r(x: float) -> float:
    return round(float(x), 2)


def _heading(deg: float) -> float:
    """A math angle in degrees, in [-180, 180)."""
    return _r((deg + 180.0) % 360.0 - 180.0)


def ring(count: int, radius_m: float, *, hub_m: float | None = None, margin_m: float = 200.0,
         pairs: list[list[str]] | None = None, time_limit_s: float = 900.0) -> dict[str, Any]:
    """``count`` vehicles on a circle of ``radius_m``; vehicle i flies from station ``S<i>`` to the
    station opposite. ``hub_m``: a round obstacle of that radius at the centre. ``pairs``: the
    mission's ``sightline.pairs`` (default: none named, the paper's pair)."""
    side = 2.0 * (radius_m + margin_m)
    c = side / 2.0
    stations: dict[str, list[float]] = {}
    vehicles: list[dict[str, Any]] = []
    for i in range(count):
        angle = 2.0 * math.pi * i / count
        stations[f"S{i}"] = [_r(c + radius_m * math.cos(angle)), _r(c + radius_m * math.sin(angle))]
        vehicles.append({"name": f"v{i}", "start": f"S{i}", "goal": f"S{(i + count // 2) % count}",
                         "initial_heading_deg": _heading(math.degrees(angle) + 180.0)})
    doc: dict[str, Any] = {
        "name": f"ring{count}" + (f"_hub{hub_m:g}" if hub_m else ""),
        "description": f"{count} vehicles on a {radius_m:g} m ring, each to the opposite point through the centre",
        "area": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": _r(side), "y_max_m": _r(side)},
        "stations": stations, "vehicles": vehicles, "safety": {"time_limit_s": time_limit_s}}
    if hub_m:
        doc["obstacles"] = [{"id": "hub", "shape": "circle", "center": [_r(c), _r(c)], "radius_m": _r(hub_m)}]
    if pairs:
        doc["sightline"] = {"pairs": pairs}
    return doc


def crossing_lanes(lanes: int, gap_m: float, length_m: float = 1200.0, *,
                   time_limit_s: float = 900.0) -> dict[str, Any]:
    """``lanes`` vehicles flying east (``e<i>``, from ``W<i>`` to ``E<i>``) across ``lanes`` flying
    north (``n<i>``, from ``S<i>`` to ``N<i>``), lanes ``gap_m`` apart, crossing in the middle of a
    square ``length_m`` + 200 m wide; listed e0, n0, e1, n1, ..."""
    side = length_m + 200.0
    stations: dict[str, list[float]] = {}
    vehicles: list[dict[str, Any]] = []
    for i in range(lanes):
        lane = side / 2.0 + gap_m * (i - (lanes - 1) / 2.0)
        stations[f"W{i}"], stations[f"E{i}"] = [50.0, _r(lane)], [_r(side - 50.0), _r(lane)]
        stations[f"S{i}"], stations[f"N{i}"] = [_r(lane), 50.0], [_r(lane), _r(side - 50.0)]
        vehicles.append({"name": f"e{i}", "start": f"W{i}", "goal": f"E{i}", "initial_heading_deg": 0.0})
        vehicles.append({"name": f"n{i}", "start": f"S{i}", "goal": f"N{i}", "initial_heading_deg": 90.0})
    return {"name": f"crossing{lanes}x{lanes}_gap{gap_m:g}",
            "description": f"{lanes} lanes east across {lanes} lanes north, {gap_m:g} m apart",
            "area": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": _r(side), "y_max_m": _r(side)},
            "stations": stations, "vehicles": vehicles, "safety": {"time_limit_s": time_limit_s}}


def corridor(each_way: int, width_m: float, *, length_m: float = 700.0, inflation_ratio: float = 0.1,
             time_limit_s: float = 900.0) -> dict[str, Any]:
    """A corridor ``width_m`` wide (between the true walls) and ``length_m`` long through the middle
    of an 1800 x 900 m area, flown by ``each_way`` vehicles east (``e<i>``) and as many west
    (``w<i>``) at once, each to the far end's station mirrored across the corridor's axis."""
    area_x, area_y = 1800.0, 900.0
    wall = (area_y - width_m) / 2.0
    obstacles = [
        {"id": "north_wall", "shape": "rectangle", "center": [area_x / 2.0, _r(area_y - wall / 2.0)],
         "width_m": length_m, "height_m": _r(wall)},
        {"id": "south_wall", "shape": "rectangle", "center": [area_x / 2.0, _r(wall / 2.0)],
         "width_m": length_m, "height_m": _r(wall)}]
    stations: dict[str, list[float]] = {}
    for i in range(each_way):
        y = _r(area_y / 2.0 + 120.0 * (i - (each_way - 1) / 2.0))
        stations[f"W{i}"], stations[f"E{i}"] = [80.0, y], [_r(area_x - 80.0), y]
    vehicles: list[dict[str, Any]] = []
    for i in range(each_way):
        mirror = each_way - 1 - i
        vehicles.append({"name": f"e{i}", "start": f"W{i}", "goal": f"E{mirror}", "initial_heading_deg": 0.0})
        vehicles.append({"name": f"w{i}", "start": f"E{i}", "goal": f"W{mirror}", "initial_heading_deg": 180.0})
    return {"name": f"corridor{each_way}x2_w{width_m:g}",
            "description": f"a {width_m:g} m corridor flown both ways by {each_way} vehicles each way",
            "area": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": area_x, "y_max_m": area_y},
            "stations": stations, "obstacles": obstacles, "vehicles": vehicles,
            "planner": {"inflation_ratio": inflation_ratio}, "safety": {"time_limit_s": time_limit_s}}
