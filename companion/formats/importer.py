"""``companion import``: a QGC ``.plan`` or a GeoJSON file (plus an optional base mission) to mission YAML.

The imported file gives the geometry (origin, area, obstacles, and stations from GeoJSON); the
base mission, when given, gives everything else (stations, vehicles, planner and safety). Without
a base, a ``.plan``'s planned home and landing (or last waypoint) are the stations A and B, and
two stations make the paper's pair (a flies A to B, b flies B to A) with the default settings.
The result is validated by the one mission loader before anything is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from companion.formats.geojson import GeoJsonError, geojson_to_document
from companion.formats.qgc_plan import PlanFormatError, fences_to_document
from uav_model.mission import Mission, MissionError, mission_from_data
from uav_model.mission_read import load_json, load_yaml, read_text


class ImportError_(ValueError):
    """An input that cannot become a mission; ``str()`` is one line naming the file."""


def _read_json(path: Path) -> Any:
    """The file's JSON, read as a mission file is (size cap, regular files only, finite numbers)."""
    try:
        return load_json(read_text(path), str(path))
    except MissionError as exc:
        raise ImportError_(str(exc)) from None


def _read_base(path: Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    data, _ = load_yaml(read_text(path), str(path))
    if not isinstance(data, dict):
        raise ImportError_(f"{path}: the base mission must be a YAML mapping")
    return data


def parts_from_file(path: Path) -> dict[str, Any]:
    """Mission parts from a ``.plan`` or a GeoJSON file, recognised by content."""
    doc = _read_json(path)
    try:
        if isinstance(doc, dict) and doc.get("fileType") == "Plan":
            return fences_to_document(doc, str(path))
        if isinstance(doc, dict) and doc.get("type") == "FeatureCollection":
            return geojson_to_document(doc, str(path))
    except (PlanFormatError, GeoJsonError) as exc:
        raise ImportError_(str(exc)) from None
    raise ImportError_(f"{path}: neither a QGroundControl plan (fileType 'Plan') nor a GeoJSON FeatureCollection")


def merged_document(path: Path, base: Path | None = None) -> dict[str, Any]:
    """The mission document: the imported geometry over the base mission (or a default pair)."""
    parts = parts_from_file(path)
    doc = _read_base(base)
    if base is None and "route_stations" in parts:
        parts.setdefault("stations", parts["route_stations"])
    doc.setdefault("name", path.stem)
    if "origin" in parts and "origin" not in doc:
        doc["origin"] = parts["origin"]
    for key in ("area", "obstacles"):
        if key in parts:
            doc[key] = parts[key]
    if parts.get("stations"):
        doc["stations"] = {**doc.get("stations", {}), **parts["stations"]}
    if "vehicles" not in doc:
        stations = list(doc.get("stations", {}))
        if len(stations) != 2:
            raise ImportError_(f"{path}: no vehicles to fly: the file names {len(stations)} station(s) (a .plan: "
                               f"a planned home and a landing or waypoint elsewhere; GeoJSON: two station "
                               f"points); give --base MISSION.yaml for the stations and vehicles")
        a, b = stations
        doc["vehicles"] = [{"name": "a", "start": a, "goal": b}, {"name": "b", "start": b, "goal": a}]
    return doc


def import_mission(path: Path, base: Path | None = None) -> tuple[dict[str, Any], Mission]:
    """The merged document and the mission it validates to (raises ImportError_ or MissionError)."""
    doc = merged_document(path, base)
    return doc, mission_from_data(doc, str(path))
