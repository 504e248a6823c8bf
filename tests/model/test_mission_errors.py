"""Every mistake in a mission file is reported at once, and lat/lon geometry is read exactly."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from uav_model import frames
from uav_model.mission import MissionError, load_mission, parse_mission, shared_goals

ROOT = Path(__file__).resolve().parents[2]
FIVE = ROOT / "tests" / "data" / "many_mistakes" / "five_mistakes.yaml"

GEO_MISSION = """
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488}
area:
  south_west: {lat_deg: 47.397742, lon_deg: 8.545594}
  north_east: {lat_deg: 47.4157, lon_deg: 8.5722}
stations:
  A: {lat_deg: 47.3986, lon_deg: 8.5469}
  B: [1900, 1900]
obstacles:
  - {id: O, shape: circle, center: {lat_deg: 47.4067, lon_deg: 8.5589}, radius_m: 300}
  - id: P
    shape: polygon
    vertices: [{lat_deg: 47.4020, lon_deg: 8.5500}, {lat_deg: 47.4030, lon_deg: 8.5500}, {lat_deg: 47.4025, lon_deg: 8.5510}]
vehicles:
  - {name: a, start: A, goal: B}
  - {name: b, start: B, goal: A}
"""


def test_a_file_with_five_mistakes_reports_all_five_one_per_line():
    with pytest.raises(MissionError) as info:
        load_mission(FIVE)
    lines = str(info.value).splitlines()
    assert len(lines) == 5 == len(info.value.problems)
    assert [ln.split(": ")[1] for ln in lines] == [
        "stations.B", "obstacles[0].radius_m", "obstacles[1].colour", "vehicles[0].speed_m_s", "vehicles[1].goal"]
    assert all(ln.startswith(f"{FIVE}:") for ln in lines)
    assert [p.line for p in info.value.problems] == sorted(p.line for p in info.value.problems)


def test_the_combined_error_survives_pickling():
    import pickle

    with pytest.raises(MissionError) as info:
        load_mission(FIVE)
    again = pickle.loads(pickle.dumps(info.value))
    assert str(again) == str(info.value) and len(again.problems) == 5


def test_geodetic_geometry_lands_where_the_frames_module_puts_it():
    m = parse_mission(GEO_MISSION, "geo.yaml")
    origin = m.origin
    ax, ay, _ = frames.geodetic_to_local(origin, 47.3986, 8.5469)
    assert m.stations["A"] == pytest.approx((ax, ay), abs=1e-9)
    assert m.stations["B"] == (1900.0, 1900.0)  # metres still welcome beside lat/lon
    assert (m.world.x_min_m, m.world.y_min_m) == pytest.approx((0.0, 0.0), abs=1e-6)
    ex, ny, _ = frames.geodetic_to_local(origin, 47.4157, 8.5722)
    assert (m.world.x_max_m, m.world.y_max_m) == pytest.approx((ex, ny))
    circle = next(o for o in m.world.obstacles if o.id == "O")
    cx, cy, _ = frames.geodetic_to_local(origin, 47.4067, 8.5589)
    assert circle.center == pytest.approx((cx, cy))
    poly = next(o for o in m.world.obstacles if o.id == "P")
    corners = list(poly.footprint.exterior.coords)
    for lat, lon in [(47.4020, 8.5500), (47.4030, 8.5500), (47.4025, 8.5510)]:
        x, y, _ = frames.geodetic_to_local(origin, lat, lon)
        assert min(math.hypot(x - cx_, y - cy_) for cx_, cy_ in corners) < 1e-6


def test_a_latlon_pair_typed_as_metres_is_caught_either_way_round():
    for pair in ("[47.3986, 8.5469]", "[8.5469, 47.3986]"):
        text = GEO_MISSION.replace("B: [1900, 1900]", f"B: {pair}")
        with pytest.raises(MissionError, match=r"stations\.B: .* looks like latitude/longitude"):
            parse_mission(text, "slip.yaml")


def test_a_shared_goal_that_separation_forbids_is_refused():
    text = GEO_MISSION.replace("- {name: b, start: B, goal: A}", "- {name: b, start: B, goal: A}\n  - {name: c, start: B, goal: A}")
    with pytest.raises(MissionError, match=r"vehicles\[2\]\.goal: station 'A' is already the goal of vehicle 'b'"):
        parse_mission(text, "x.yaml")
    # With an arrival disc wide enough for both, it is allowed (and `validate` warns).
    wide = text + "safety: {arrival_radius_m: 40, min_separation_m: 50}\n"
    assert shared_goals(parse_mission(wide, "x.yaml")) == {"A": ["b", "c"]}
