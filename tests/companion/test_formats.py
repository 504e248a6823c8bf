"""QGroundControl .plan and GeoJSON: round trips keep the geometry, bad files get one clear line."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from shapely.geometry import Polygon

from companion.app.flight_plan import prepare
from companion.formats.importer import ImportError_, import_mission
from companion.app.fence import mission_fence
from companion.formats.qgc_plan import plan_document
from companion.scenarios import ScenarioConfig, generate_scenario
from uav_model.fence_margin import fence_standoff_m
from uav_model import frames
from uav_model.mission import load_mission, mission_from_data

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
TOLERANCE_M = 0.1


def _document(plan, vehicle):
    """The .plan document of ``vehicle``, from what the app uploads."""
    return plan_document(plan.mission, vehicle, plan.waypoints(vehicle), mission_fence(plan.mission))


def _same_geometry(a, b) -> None:
    wa, wb = a.world, b.world
    for attr in ("x_min_m", "y_min_m", "x_max_m", "y_max_m", "geofence_margin_m"):
        assert getattr(wb, attr) == pytest.approx(getattr(wa, attr), abs=TOLERANCE_M), attr
    static_a = {o.id: o for o in wa.static_obstacles}
    static_b = {o.id: o for o in wb.static_obstacles}
    assert static_a.keys() == static_b.keys()
    for oid, oa in static_a.items():
        ob = static_b[oid]
        # Hausdorff distance between the true footprints, and between the inflated ones.
        assert oa.footprint.hausdorff_distance(ob.footprint) < TOLERANCE_M, oid
        assert oa.inflated.hausdorff_distance(ob.inflated) < TOLERANCE_M, oid


def _round_trip(mission_path: Path, tmp_path: Path):
    mission = load_mission(mission_path)
    plan = prepare(mission)
    plan_file = tmp_path / "a.plan"
    plan_file.write_text(json.dumps(_document(plan, mission.vehicles[0])))
    _, again = import_mission(plan_file, base=mission_path)
    return mission, again


def test_reference_yaml_to_plan_to_yaml_keeps_the_geometry(tmp_path):
    mission, again = _round_trip(REFERENCE, tmp_path)
    _same_geometry(mission, again)
    assert again.stations == mission.stations


@pytest.mark.parametrize("index", [0, 1, 2])
def test_random_scenarios_round_trip_through_plan(tmp_path, index):
    """Circles, squares and triangles, rotated: all come back within 0.1 m."""
    doc = dict(generate_scenario(2026, index, ScenarioConfig()).doc)
    doc["obstacles"] = [o for o in doc["obstacles"] if "motion" not in o]  # a .plan holds fences only
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(doc))
    mission, again = _round_trip(path, tmp_path)
    _same_geometry(mission, again)


def test_plan_fences_lie_the_standoff_inside_the_inflated_obstacles_and_are_the_geofence(tmp_path):
    mission = load_mission(REFERENCE)
    doc = _document(prepare(mission), mission.vehicles[0])
    assert doc["version"] == 1 and doc["mission"]["version"] == 2
    assert doc["geoFence"]["version"] == 2 and doc["rallyPoints"]["version"] == 2
    (circle,) = doc["geoFence"]["circles"]
    # The inflated 600 m disk less the fence standoff (v^2 / 2a: 10 m/s, the unicycle's 8 m/s^2).
    assert circle["inclusion"] is False and circle["circle"]["radius"] == pytest.approx(600.0 - 6.25)
    assert fence_standoff_m(mission) == pytest.approx(6.25)
    (area,) = doc["geoFence"]["polygons"]
    ring = Polygon([frames.geodetic_to_local(mission.origin, lat, lon)[:2] for lat, lon in area["polygon"]])
    assert ring.hausdorff_distance(mission.world.geofence) < TOLERANCE_M
    # As QGroundControl's own plans: take-off first, the route the companion uploads (waypoint for
    # waypoint), and a landing at the goal last; numbered from 1.
    vehicle = mission.vehicles[0]
    sent = prepare(mission).waypoints(vehicle)
    items = doc["mission"]["items"]
    assert [i["command"] for i in items] == [22] + [16] * len(sent) + [21]
    assert [i["doJumpId"] for i in items] == list(range(1, len(items) + 1))
    assert [(i["params"][4], i["params"][5]) for i in items[1:-1]] == [(w.lat_deg, w.lon_deg) for w in sent]
    assert items[0]["Altitude"] == vehicle.cruise_alt_m
    home = doc["mission"]["plannedHomePosition"]
    assert frames.geodetic_to_local(mission.origin, *home[:2])[:2] == pytest.approx(vehicle.start_enu_m, abs=0.01)
    landing = frames.geodetic_to_local(mission.origin, *items[-1]["params"][4:6])[:2]
    assert landing == pytest.approx(vehicle.goal_enu_m, abs=0.01)
    # QGroundControl's top-level keys, as in its own file (tests/data/small_mission.plan).
    theirs = json.loads((ROOT / "tests" / "data" / "small_mission.plan").read_text())
    assert doc.keys() == theirs.keys() and doc["fileType"] == "Plan" and doc["groundStation"] == "QGroundControl"
    assert set(theirs["mission"]) <= set(doc["mission"])
    assert all(set(theirs["mission"]["items"][0]) == set(i) for i in items)


def test_our_plan_imports_without_a_base_with_its_start_and_goal(tmp_path):
    mission = load_mission(REFERENCE)
    plan = prepare(mission)
    b = mission.vehicles[1]
    path = tmp_path / "b.plan"
    path.write_text(json.dumps(_document(plan, b)))
    _, again = import_mission(path)
    _same_geometry(mission, again)
    assert again.origin == mission.origin
    # The .plan's home and landing are b's stations, under their own names.
    assert again.stations[b.start] == pytest.approx(b.start_enu_m, abs=TOLERANCE_M)
    assert again.stations[b.goal] == pytest.approx(b.goal_enu_m, abs=TOLERANCE_M)
    first = again.vehicles[0]
    assert (first.start, first.goal) == (b.start, b.goal)


def test_qgroundcontrols_own_plan_imports_without_a_base():
    """Its planned home is the start, its landing the end; no fence: the area is drawn around them."""
    path = ROOT / "tests" / "data" / "small_mission.plan"
    doc, mission = import_mission(path)
    theirs = json.loads(path.read_text())
    home, land = theirs["mission"]["plannedHomePosition"], theirs["mission"]["items"][-1]["params"]
    assert mission.stations["A"] == pytest.approx(frames.geodetic_to_local(mission.origin, *home[:2])[:2], abs=0.01)
    assert mission.stations["B"] == pytest.approx(frames.geodetic_to_local(mission.origin, *land[4:6])[:2], abs=0.01)
    for x, y in mission.stations.values():
        assert mission.world.x_min_m < x < mission.world.x_max_m and mission.world.y_min_m < y < mission.world.y_max_m


def test_a_plan_without_a_home_or_an_end_asks_for_a_base_in_one_line(tmp_path):
    theirs = json.loads((ROOT / "tests" / "data" / "small_mission.plan").read_text())
    theirs["mission"]["items"] = theirs["mission"]["items"][:1]  # only the take-off: no end
    path = tmp_path / "takeoff_only.plan"
    path.write_text(json.dumps(theirs))
    with pytest.raises(ImportError_, match="--base") as info:
        import_mission(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


GEOJSON = {
    "type": "FeatureCollection",
    "features": [
        {"type": "Feature", "properties": {"role": "area", "geofence_margin_m": 150},
         "geometry": {"type": "Polygon", "coordinates": [[[8.545594, 47.397742], [8.5722, 47.397742],
                                                          [8.5722, 47.4157], [8.545594, 47.4157],
                                                          [8.545594, 47.397742]]]}},
        {"type": "Feature", "properties": {"station": "A"},
         "geometry": {"type": "Point", "coordinates": [8.5469, 47.3986]}},
        {"type": "Feature", "properties": {"station": "B"},
         "geometry": {"type": "Point", "coordinates": [8.5705, 47.4148]}},
        {"type": "Feature", "properties": {"id": "lake", "radius_m": 250},
         "geometry": {"type": "Point", "coordinates": [8.5589, 47.4067]}},
        {"type": "Feature", "properties": {"id": "barn"},
         "geometry": {"type": "Polygon", "coordinates": [[[8.5500, 47.4020], [8.5500, 47.4030],
                                                          [8.5510, 47.4025], [8.5500, 47.4020]]]}},
        {"type": "Feature", "properties": {"id": "truck", "radius_m": 40,
                                           "motion": {"type": "shuttle", "to": [8.5650, 47.4000], "speed_m_s": 3}},
         "geometry": {"type": "Point", "coordinates": [8.5600, 47.4000]}},
    ],
}


def test_geojson_to_yaml_keeps_the_geometry(tmp_path):
    path = tmp_path / "zones.geojson"
    path.write_text(json.dumps(GEOJSON))
    doc, mission = import_mission(path)
    origin = mission.origin
    assert [v.name for v in mission.vehicles] == ["a", "b"]  # two stations: the paper's pair

    def local(lon, lat):
        return frames.geodetic_to_local(origin, lat, lon)[:2]

    assert mission.stations["A"] == pytest.approx(local(8.5469, 47.3986), abs=TOLERANCE_M)
    lake = next(o for o in mission.world.obstacles if o.id == "lake")
    assert lake.center == pytest.approx(local(8.5589, 47.4067), abs=TOLERANCE_M) and lake.size_m == 250
    barn = next(o for o in mission.world.obstacles if o.id == "barn")
    expected = Polygon([local(*p) for p in GEOJSON["features"][4]["geometry"]["coordinates"][0]])
    assert barn.footprint.hausdorff_distance(expected) < TOLERANCE_M
    truck = next(o for o in mission.world.obstacles if o.id == "truck")
    assert truck.is_moving
    assert (mission.world.x_max_m, mission.world.y_max_m) == pytest.approx(local(8.5722, 47.4157), abs=TOLERANCE_M)
    # And the written YAML loads to the same mission.
    out = tmp_path / "m.yaml"
    out.write_text(yaml.safe_dump(doc))
    _same_geometry(mission, load_mission(out))


@pytest.mark.parametrize("content, message", [
    ("{not json", "not JSON"),
    ('{"type": "Topology"}', "neither a QGroundControl plan"),
    ('{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, '
     '"geometry": {"type": "LineString", "coordinates": [[8.5, 47.4], [8.6, 47.4]]}}]}', "features[0]: a LineString"),
    ('{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"radius_m": 5}, '
     '"geometry": {"type": "Point", "coordinates": [200.0, 47.4]}}]}',
     "features[0]: [200, 47.4] is out of range for [lon, lat] in degrees"),
])
def test_bad_files_get_one_line_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.geojson"
    path.write_text(content)
    with pytest.raises(ImportError_, match=re.escape(message)) as info:
        import_mission(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_geojson_without_vehicles_or_two_stations_asks_for_a_base(tmp_path):
    doc = {"type": "FeatureCollection", "features": GEOJSON["features"][3:4]}
    path = tmp_path / "only_obstacles.geojson"
    path.write_text(json.dumps(doc))
    with pytest.raises(ImportError_, match="--base"):
        import_mission(path)
    _, mission = import_mission(path, base=REFERENCE)
    assert [o.id for o in mission.world.obstacles] == ["lake"]
    mission_from_data(yaml.safe_load(REFERENCE.read_text()))  # the base itself is untouched
