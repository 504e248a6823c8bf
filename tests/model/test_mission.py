"""The mission loader: good files load into typed objects; bad ones name file, line and field."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from uav_model.mission import (VARIANTS, MissionError, Normalisation, SightlineCritic, load_mission, mission_schema,
                               parse_mission)

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
BAD = ROOT / "tests" / "data" / "bad_missions"


def test_reference_mission_matches_spec_section_1():
    m = load_mission(REFERENCE)
    a, b = m.vehicles
    assert (a.name, b.name) == ("a", "b")
    assert a.start_enu_m == (0.0, 0.0) and a.goal_enu_m == pytest.approx((3181.98, 3181.98))
    assert b.initial_heading_deg == -135.0
    assert a.max_yaw_rate_rad_s == pytest.approx(1.0 / 3.0)
    assert m.planner.prediction_time_for(a) == 11.0
    (fire,) = m.world.obstacles
    assert fire.inflated_radius_m == pytest.approx(600.0)
    assert math.hypot(*fire.center) == pytest.approx(1000.0, abs=0.01)
    assert [v.name for v in m.by_priority] == ["a", "b"]
    assert (a.system_id, b.system_id) == (1, 2)
    assert a.connection == "udpin://0.0.0.0:14540" and b.connection == "udpin://0.0.0.0:14541"


@pytest.mark.parametrize(
    ("name", "field", "line", "words"),
    [
        ("unknown_key.yaml", "planner.grid_resolution", 34, "unknown key"),
        ("wrong_type.yaml", "vehicles[0].speed_m_s", 20, "expected number"),
        ("out_of_range.yaml", "planner.yaw_rate_samples", 34, "minimum of 3"),
        ("negative_radius.yaml", "obstacles[0].radius_m", 15, "minimum of 0"),
        ("station_in_obstacle.yaml", "stations.A", 9, "inside obstacle 'fire'"),
        ("unknown_station.yaml", "vehicles[0].goal", 19, "unknown station 'C'"),
        ("bad_variant.yaml", "planner.variant", 32, "is not one of"),
        ("duplicate_key.yaml", "", 21, "duplicate key 'speed_m_s'"),
        ("yaml_syntax.yaml", "", 10, "YAML syntax"),
    ],
)
def test_bad_missions_name_file_line_and_field(name, field, line, words):
    with pytest.raises(MissionError) as info:
        load_mission(BAD / name)
    err = info.value
    assert err.field_path == field
    assert err.line == line
    message = str(err)
    assert message.startswith(f"{BAD / name}:{line}: ")
    assert words in message
    assert "\n" not in message


def test_missing_file_is_a_mission_error():
    with pytest.raises(MissionError, match="file not found"):
        load_mission(ROOT / "missions" / "no_such_mission.yaml")


@pytest.mark.parametrize("text", ["", "- just\n- a list\n", "42\n"])
def test_non_mapping_documents_are_refused(text):
    with pytest.raises(MissionError, match="must be a YAML mapping"):
        parse_mission(text, "x.yaml")


def test_polygon_must_be_simple():
    text = REFERENCE.read_text().replace(
        "obstacles:\n",
        "obstacles:\n  - shape: polygon\n    vertices: [[1500, 2000], [2000, 2500], [2000, 2000], [1500, 2500]]\n",
    )
    with pytest.raises(MissionError, match="self-intersecting") as info:
        parse_mission(text, "bowtie.yaml")
    assert info.value.field_path == "obstacles[0].vertices"


def test_motion_fields_are_checked_per_type():
    text = REFERENCE.read_text().replace(
        "    radius_m: 500.0\n",
        "    radius_m: 500.0\n    motion: {type: shuttle, pivot: [1, 2], speed_m_s: 3}\n",
    )
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    assert info.value.field_path.startswith("obstacles[0].motion")


def test_schema_variant_enum_is_the_code_enum():
    assert tuple(mission_schema()["$defs"]["planner"]["properties"]["variant"]["enum"]) == VARIANTS


def test_with_variant_refuses_unknown_variant():
    m = load_mission(REFERENCE)
    assert m.with_variant("dwa").planner.variant == "dwa"
    with pytest.raises(MissionError, match="unknown variant"):
        m.with_variant("rrt")


def test_a_document_in_memory_validates_like_its_yaml():
    import yaml

    from uav_model.mission import mission_from_data

    text = Path("missions/paper_reference.yaml").read_text()
    assert repr(mission_from_data(yaml.safe_load(text), "ref")) == repr(parse_mission(text, "ref"))
    doc = yaml.safe_load(text)
    doc["planner"] = {"yaw_rate_samples": 1}
    with pytest.raises(MissionError, match=r"^ref: planner.yaw_rate_samples: 1 is less than the minimum of 3$"):
        mission_from_data(doc, "ref")
    with pytest.raises(MissionError, match="must be a mapping"):
        mission_from_data(["not", "a", "mapping"], "ref")


def test_plant_defaults_to_the_multicopter_and_the_reference_keeps_the_paper_unicycle():
    from uav_model.plant import Plant

    assert tuple(mission_schema()["properties"]["plant"]["enum"]) == tuple(p.value for p in Plant)
    text = REFERENCE.read_text()
    assert load_mission(REFERENCE).plant is Plant.UNICYCLE  # Tables I-IV stay reproducible
    assert parse_mission(text.replace("plant: unicycle", ""), "m.yaml").plant is Plant.MULTICOPTER
    line = text.splitlines().index(next(s for s in text.splitlines() if s.startswith("plant:"))) + 1
    with pytest.raises(MissionError, match=rf"^m.yaml:{line}: plant: 'bicycle' is not one of multicopter, unicycle$"):
        parse_mission(text.replace("plant: unicycle", "plant: bicycle"), "m.yaml")


def test_speed_window_and_critic_settings_are_read_and_default_to_the_variant():
    m = load_mission(REFERENCE)
    assert m.planner.speed_samples is None and m.planner.sightline_critic is None and m.planner.normalisation is None
    data = yaml.safe_load(Path(REFERENCE).read_text())
    data.setdefault("planner", {}).update(speed_samples=5, min_speed_m_s=2.0, sightline_critic="sloped",
                                          normalisation="fixed", weights={"speed": 0.25})
    p = parse_mission(yaml.safe_dump(data), "x.yaml").planner
    assert (p.speed_samples, p.min_speed_m_s, p.weight_speed) == (5, 2.0, 0.25)
    assert p.sightline_critic is SightlineCritic.SLOPED and p.normalisation is Normalisation.FIXED


def test_the_final_approach_setting_is_read_and_defaults_to_the_plants():
    assert load_mission(REFERENCE).planner.final_approach is None
    data = yaml.safe_load(Path(REFERENCE).read_text())
    for value in (True, False):
        data.setdefault("planner", {})["final_approach"] = value
        assert parse_mission(yaml.safe_dump(data), "x.yaml").planner.final_approach is value
    data["planner"]["final_approach"] = "yes"
    with pytest.raises(MissionError, match="final_approach"):
        parse_mission(yaml.safe_dump(data), "x.yaml")


def test_a_minimum_speed_above_a_vehicles_speed_is_refused():
    data = yaml.safe_load(Path(REFERENCE).read_text())
    data.setdefault("planner", {})["min_speed_m_s"] = 12.0
    with pytest.raises(MissionError, match="min_speed_m_s"):
        parse_mission(yaml.safe_dump(data), "x.yaml")
