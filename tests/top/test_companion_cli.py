"""The flying subcommands' input handling, in-process: exit codes and one-line messages."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from companion.cli import main
from companion.cli.options import plant_flown
from uav_model.mission import mission_schema

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
BAD_MISSIONS = sorted((ROOT / "tests" / "data" / "bad_missions").glob("*.yaml"))


def _one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


@pytest.mark.parametrize("command", ["validate", "run"])
@pytest.mark.parametrize("path", BAD_MISSIONS, ids=lambda p: p.stem)
def test_bad_missions_exit_2_with_one_line_naming_the_file(command, path, capsys):
    # "run" refuses before it starts a stub or opens a connection (nothing to arm).
    assert main([command, str(path)]) == 2
    err = capsys.readouterr()
    line = _one_line(err.err)
    assert line.startswith(str(path)), line
    assert err.out == ""


def test_unreachable_goal_names_the_goal_field(capsys):
    assert main(["validate", str(ROOT / "tests/data/bad_missions/unreachable_goal.yaml")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "].goal: no path" in line


def test_validate_reports_routes_for_a_good_mission(capsys):
    assert main(["validate", str(REFERENCE)]) == 0
    out = capsys.readouterr().out
    assert "ok" in out and "a:" in out and "nodes" in out
    assert "occlusion certificate (a never waits" in out and "at closest approach: infeasible under the rule" in out


@pytest.mark.parametrize("connects, message", [
    (["a=udpin://0.0.0.0:1"], "--connect missing for vehicle(s) b"),
    (["a=udpin://0.0.0.0:1", "c=udpin://0.0.0.0:2"], "no vehicle 'c'"),
    (["a=udpin://0.0.0.0:1", "a=udpin://0.0.0.0:2"], "given twice"),
])
def test_connect_must_name_each_vehicle_once(connects, message, capsys):
    args = ["run", str(REFERENCE)]
    for c in connects:
        args += ["--connect", c]
    assert main(args) == 2
    assert message in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize("bad", ["a", "a=", "=udpin://0.0.0.0:1", "a=14540"])
def test_malformed_connect_is_a_usage_error(bad, capsys):
    with pytest.raises(SystemExit) as info:
        main(["run", str(REFERENCE), "--connect", bad])
    assert info.value.code == 2
    assert "--connect" in capsys.readouterr().err


def test_schema_prints_the_published_schema(capsys):
    assert main(["schema"]) == 0
    assert json.loads(capsys.readouterr().out) == mission_schema()


def test_plan_writes_routes_and_a_plot(tmp_path, capsys):
    assert main(["plan", str(REFERENCE), "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "routes.json").read_text())
    assert set(doc["vehicles"]) == {"a", "b"}
    a = doc["vehicles"]["a"]
    assert a["nodes_sparse"] == len(a["waypoints_enu_m"]) == len(a["waypoints_geodetic"])
    assert a["lower_bound_s"] == pytest.approx(473.8, abs=0.1)
    cert = doc["occlusion_certificate"]
    assert (cert["higher"], cert["lower"], cert["whole_flight"], cert["closest_approach"]) == ("a", "b", False, False)
    assert 0 < cert["closest_approach_min_hold_s"] < cert["whole_flight_min_hold_s"]
    assert (tmp_path / "trajectory.png").stat().st_size > 10_000


@pytest.mark.parametrize("command", ["run", "plan"])
def test_an_output_directory_that_cannot_exist_is_bad_input(command, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main([command, str(REFERENCE), "--out", str(blocker / "out")]) == 2
    assert "cannot create the directory" in _one_line(capsys.readouterr().err)


STRAIGHT = """
name: straight
plant: unicycle
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1200, y_max_m: 400}
stations: {A: [100, 200], B: [1100, 200]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 90}
"""


def test_plant_option_flies_the_mission_with_the_other_plant(tmp_path):
    # The PX4-like multicopter's tilt limit holds 9.8 m/s against drag, so 1 km at a commanded 10 m/s
    # takes it longer than the paper's unicycle, which flies exactly 10 m/s: --plant must reach the runner.
    mission = tmp_path / "straight.yaml"
    mission.write_text(STRAIGHT)
    times = {}
    for plant in (None, "multicopter"):
        out = tmp_path / str(plant)
        assert main(["simulate", str(mission), "--out", str(out)] + (["--plant", plant] if plant else [])) == 0
        times[plant] = json.loads((out / "summary.json").read_text())["vehicles"]["a"]["flight_time_s"]
    assert times["multicopter"] > 1.02 * times[None]  # 109.3 s against 105.5 s when written


def test_an_unknown_plant_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", "table1", "--plant", "fixedwing"])
    assert exc.value.code == 2
    assert "--plant" in capsys.readouterr().err


def test_run_on_px4_plans_for_a_multicopter_unless_told_otherwise():
    # PX4 SIH flies a quadrotor whatever the mission file says: the planner's fence margins and
    # tracking lag must be the multicopter's (the paper's reference is written for the unicycle).
    assert plant_flown(argparse.Namespace(sim="px4", plant=None)) == "multicopter"
    assert plant_flown(argparse.Namespace(sim="px4", plant="unicycle")) == "unicycle"
    assert plant_flown(argparse.Namespace(sim="stub", plant=None)) is None  # the stub flies the mission's plant
    assert plant_flown(argparse.Namespace(sim="stub", plant="multicopter")) == "multicopter"
    assert plant_flown(argparse.Namespace()) is None  # validate, upload: the mission's
