"""A hostile corpus for the mission loader: non-finite numbers in every kind of numeric field,
out-of-range lat/lon, oversized, deeply nested and alias-bomb documents, files that are not
files. Each is refused with one line per problem, a bounded message, and never a traceback."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from uav_model.mission import MissionError, load_mission, parse_mission
from uav_model.mission_limits import MAX_DEPTH, MAX_FILE_BYTES, MAX_NODES

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = (ROOT / "missions" / "paper_reference.yaml").read_text()

BASE = """
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 2000, y_max_m: 2000, geofence_margin_m: 100}
stations: {A: [100, 100], B: [1900, 1900]}
obstacles:
  - {id: c, shape: circle, center: [1000, 1000], radius_m: 100}
  - {id: r, shape: rectangle, center: [400, 1500], width_m: 100, height_m: 50, rotation_deg: 10}
  - {id: t, shape: triangle, center: [1500, 400], circumradius_m: 80}
  - {id: p, shape: polygon, vertices: [[600, 600], [700, 600], [650, 700]]}
  - {id: m, shape: circle, center: {lat_deg: 47.4067, lon_deg: 8.5589}, radius_m: 50,
     motion: {type: shuttle, to: [1200, 300], speed_m_s: 3}}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 30, max_accel_m_s2: 3, cruise_alt_m: 50,
     initial_heading_deg: 45, battery_pct: 90}
  - {name: b, start: B, goal: A}
planner: {grid_resolution_m: 20, dt_s: 0.5, prediction_time_s: 11, inflation_ratio: 0.2, acceptance_radius_m: 30,
          sightline_cap_m: 100, replan_after_s: 60, min_speed_m_s: 0,
          weights: {heading: 0.37, distance: 0.6, sightline: 0.8, speed: 0.5}}
safety: {min_separation_m: 50, arrival_radius_m: 20, time_limit_s: 2500, telemetry_timeout_s: 1}
coordination: {hold_s_max: 0, step_s: 5}
"""

# (text to replace, its NaN version's field path): one per numeric field class.
FIELDS = [
    ("lat_deg: 47.397742,", "origin.lat_deg"), ("alt_m: 488", "origin.alt_m"),
    ("x_max_m: 2000", "area.x_max_m"), ("geofence_margin_m: 100", "area.geofence_margin_m"),
    ("A: [100, 100]", "stations.A[0]"), ("center: [1000, 1000]", "obstacles[0].center[0]"),
    ("radius_m: 100}", "obstacles[0].radius_m"), ("width_m: 100", "obstacles[1].width_m"),
    ("rotation_deg: 10", "obstacles[1].rotation_deg"), ("circumradius_m: 80", "obstacles[2].circumradius_m"),
    ("[[600, 600]", "obstacles[3].vertices[0][0]"), ("lat_deg: 47.4067", "obstacles[4].center.lat_deg"),
    ("to: [1200, 300]", "obstacles[4].motion.to[0]"), ("speed_m_s: 3}", "obstacles[4].motion.speed_m_s"),
    ("speed_m_s: 10", "vehicles[0].speed_m_s"), ("turn_radius_m: 30", "vehicles[0].turn_radius_m"),
    ("max_accel_m_s2: 3", "vehicles[0].max_accel_m_s2"), ("cruise_alt_m: 50", "vehicles[0].cruise_alt_m"),
    ("initial_heading_deg: 45", "vehicles[0].initial_heading_deg"), ("battery_pct: 90", "vehicles[0].battery_pct"),
    ("grid_resolution_m: 20", "planner.grid_resolution_m"), ("dt_s: 0.5", "planner.dt_s"),
    ("prediction_time_s: 11", "planner.prediction_time_s"), ("inflation_ratio: 0.2", "planner.inflation_ratio"),
    ("acceptance_radius_m: 30", "planner.acceptance_radius_m"), ("sightline_cap_m: 100", "planner.sightline_cap_m"),
    ("replan_after_s: 60", "planner.replan_after_s"), ("min_speed_m_s: 0", "planner.min_speed_m_s"),
    ("heading: 0.37", "planner.weights.heading"), ("sightline: 0.8", "planner.weights.sightline"),
    ("min_separation_m: 50", "safety.min_separation_m"), ("arrival_radius_m: 20", "safety.arrival_radius_m"),
    ("time_limit_s: 2500", "safety.time_limit_s"), ("telemetry_timeout_s: 1", "safety.telemetry_timeout_s"),
    ("hold_s_max: 0", "coordination.hold_s_max"), ("step_s: 5", "coordination.step_s"),
]


def _nonfinite(text: str, value: str) -> str:
    key, _, rest = text.partition(": ")
    if text.startswith("[[") or text.startswith("A: [") or "center: [" in text or "to: [" in text:
        head, _, tail = text.partition("[")
        if tail.startswith("["):
            return f"{head}[[{value}, {tail[1:].split(',', 1)[1].lstrip()}"
        return f"{head}[{value}, {tail.split(',', 1)[1].lstrip()}"
    end = "," if rest.endswith(",") else "}" if rest.endswith("}") else ""
    return f"{key}: {value}{end}"


def _refused(text: str) -> MissionError:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "hostile.yaml")
    assert "Traceback" not in str(info.value)
    return info.value


def test_the_base_mission_is_valid():
    parse_mission(BASE, "base.yaml")


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
@pytest.mark.parametrize("field, path", FIELDS, ids=[p for _, p in FIELDS])
def test_a_non_finite_number_is_refused_in_every_field(field, path, value):
    assert BASE.count(field) == 1, field
    err = _refused(BASE.replace(field, _nonfinite(field, value)))
    assert any(p.field_path == path and "not a finite number" in p.reason for p in err.problems), str(err)
    assert all(p.line is not None for p in err.problems)


@pytest.mark.parametrize("written, words", [
    ("1e308", "1e+308 is greater than the maximum of 100000"),  # a number (YAML 1.1 would read a string)
    ("1e999", "inf is not a finite number"),
    ("2.5e1", None),
])
def test_a_number_in_exponent_form_is_a_number_and_held_to_its_limits(written, words):
    text = REFERENCE.replace("    radius_m: 500.0", f"    radius_m: {written}", 1)
    assert text != REFERENCE
    if words is None:
        assert parse_mission(text, "m.yaml").world.obstacles[0].size_m == 25.0
        return
    with pytest.raises(MissionError) as exc:
        parse_mission(text, "m.yaml")
    assert "obstacles[0].radius_m: " + words in str(exc.value)


def test_an_obstacle_centre_with_a_nan_latitude_is_refused_not_emptied():
    err = _refused(BASE.replace("lat_deg: 47.4067", "lat_deg: .nan"))
    assert str(err) == "hostile.yaml:10: obstacles[4].center.lat_deg: nan is not a finite number " \
                       "(NaN and infinity are refused everywhere)"


@pytest.mark.parametrize("field, bad, words", [
    ("lat_deg: 47.4067", "lat_deg: 95.5", "latitude 95.5 is out of range [-89, 89] degrees"),
    ("lon_deg: 8.5589", "lon_deg: -200", "longitude -200 is out of range [-180, 180] degrees"),
    ("lat_deg: 47.397742,", "lat_deg: -90.5,", "latitude -90.5 is out of range"),
])
def test_a_latitude_or_longitude_out_of_range_is_named_as_such(field, bad, words):
    assert words in str(_refused(BASE.replace(field, bad)))


def test_five_thousand_obstacles_name_the_limit_in_one_short_line():
    many = "obstacles:\n" + "".join(f"  - {{shape: circle, center: [{i % 50 * 30}, {i // 50 * 30}], radius_m: 1}}\n"
                                     for i in range(5000))
    text = BASE.split("obstacles:")[0] + many + "vehicles:" + BASE.split("vehicles:")[1]
    started = time.monotonic()
    err = _refused(text)
    assert time.monotonic() - started < 60  # ~3 s of CPU; generous for a loaded machine
    assert str(err) == "hostile.yaml:5: obstacles: 5000 items, more than the limit of 200"


def test_a_huge_value_is_echoed_in_at_most_about_200_characters():
    err = _refused(BASE.replace("speed_m_s: 10,", f"speed_m_s: [{', '.join(['123456789'] * 20000)}],"))
    assert "vehicles[0].speed_m_s: expected number, got list [" in str(err) and len(str(err)) < 300


def test_many_problems_show_forty_lines_and_count_the_rest():
    bad = BASE.split("vehicles:")[0].replace("obstacles:\n", "obstacles:\n" + "  - {shape: circle}\n" * 60)
    err = _refused(bad + "vehicles:" + BASE.split("vehicles:")[1])
    lines = str(err).splitlines()
    assert len(err.problems) == 60 and len(lines) == 41
    assert lines[-1] == "hostile.yaml: 20 more problems not shown (the first 40 are)"


def test_deep_nesting_is_refused_at_the_limit():
    for text in ("name: " + "[" * 5000 + "]" * 5000, "name:\n" + "".join(" " * i + "- \n" for i in range(1, 5000))):
        err = _refused(text)
        assert str(err).startswith("hostile.yaml:1: YAML syntax: nested more than") or \
            f"nested more than {MAX_DEPTH} levels deep (the limit)" in str(err), str(err)
        assert len(str(err).splitlines()) == 1


def test_an_alias_bomb_is_refused_before_it_expands():
    lines = ['x0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"x{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    text = BASE.replace("obstacles:\n", "\n".join(lines) + "\nobstacles:\n")
    started = time.monotonic()
    err = _refused(text)
    assert time.monotonic() - started < 5
    assert f"more than {MAX_NODES} values once aliases are expanded (the limit)" in str(err)
    assert len(str(err)) < 300


def test_a_few_aliases_are_fine():
    text = BASE.replace("planner: {", "planner: &p {").replace("coordination: {hold_s_max: 0, step_s: 5}",
                                                               "coordination: {hold_s_max: 0, step_s: 5}\n")
    parse_mission(text.replace("stations: {A: [100, 100]", "stations: {A: &here [100, 100], C: *here"), "ok.yaml")


def test_keys_must_be_text():
    assert "key 1.5 is not text; quote it" in str(_refused(BASE.replace("A: [100, 100]", "A: [100, 100], 1.5: [1, 1]")))


def test_the_grid_limit_is_a_mission_error():
    err = _refused(BASE.replace("grid_resolution_m: 20", "grid_resolution_m: 0.5"))
    assert "planner.grid_resolution_m: a 0.5 m grid over the geofence is 4400 x 4400 cells, more than the limit" in str(err)


@pytest.fixture
def files(tmp_path):
    big = tmp_path / "big.yaml"
    with big.open("w") as f:
        f.write("# " + "x" * 1000 + "\n")
        f.truncate(MAX_FILE_BYTES + 10)
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    (tmp_path / "latin1.yaml").write_bytes("name: caf\xe9\n".encode("latin-1"))
    (tmp_path / "dir.yaml").mkdir()
    loop = tmp_path / "loop.yaml"
    loop.symlink_to(loop)
    return tmp_path


@pytest.mark.parametrize("name, reason", [
    ("big.yaml", "file is larger than the limit of 4 MiB"),
    ("fifo.yaml", "not a regular file (a fifo, socket or device); give a mission file"),
    ("latin1.yaml", "not UTF-8 text (byte 0xe9 at offset 9)"),
    ("dir.yaml", "is a directory, not a mission file"),
    ("loop.yaml", "cannot read file: Too many levels of symbolic links"),
    ("missing.yaml", "file not found"),
])
def test_what_is_not_a_readable_mission_file_is_named(files, name, reason):
    path = files / name
    with pytest.raises(MissionError) as info:
        load_mission(path)
    assert str(info.value).startswith(f"{path}") and str(info.value).endswith(reason), str(info.value)


def test_a_device_is_refused_without_reading_it():
    with pytest.raises(MissionError, match="not a regular file"):
        load_mission("/dev/zero")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file whatever its mode")
def test_an_unreadable_file_is_named(tmp_path):
    path = tmp_path / "secret.yaml"
    path.write_text(REFERENCE)
    path.chmod(0)
    with pytest.raises(MissionError, match="cannot read file: Permission denied"):
        load_mission(path)
