"""Hostile input through the real command line, each in its own process: exit 2, one line per
problem, a bounded stderr, no traceback, and an end well within a wall-clock bound (generous:
the suite runs on loaded machines; each of these takes a few seconds of CPU)."""

from __future__ import annotations

import importlib.util
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
PLAN = ROOT / "tests" / "data" / "small_mission.plan"
WALL_S = 120


def companion(*args: str, timeout_s: float = WALL_S) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "companion", *args], capture_output=True, text=True,
                          timeout=timeout_s, env=env, cwd=ROOT)


def _refused(proc: subprocess.CompletedProcess, lines: int = 1) -> list[str]:
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and len(proc.stderr) < 5000 and proc.stdout == ""
    got = proc.stderr.splitlines()
    assert len(got) == lines, proc.stderr
    return got


def _alias_bomb() -> str:
    lines = ['x0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"x{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    return "\n".join(lines) + "\nobstacles: [*a8]\n"


@pytest.mark.parametrize("name, text, reason", [
    ("bomb.yaml", _alias_bomb(), "values once aliases are expanded (the limit)"),
    ("deep.yaml", "obstacles: " + "[" * 5000 + "]" * 5000 + "\n", "nested more than 20 levels deep (the limit)"),
    ("nan.yaml", REFERENCE.read_text().replace("center: [707.11, 707.11]", "center: {lat_deg: .nan, lon_deg: 8.55}"),
     "obstacles[0].center.lat_deg: nan is not a finite number"),
])
def test_hostile_mission_files_are_refused_in_one_line(tmp_path, name, text, reason):
    path = tmp_path / name
    path.write_text(text)
    (line,) = _refused(companion("validate", str(path)))
    assert line.startswith(f"{path}:") and reason in line


def test_a_device_is_refused_without_reading_it():
    (line,) = _refused(companion("validate", "/dev/zero"))
    assert line == "/dev/zero: not a regular file (a fifo, socket or device); give a mission file"


@pytest.mark.parametrize("change, reason", [
    (lambda fence: fence["circles"][0]["circle"].update(radius=None), "circle.radius: expected a positive number"),
    (lambda fence: fence["circles"][0]["circle"].update(center=[float("nan"), 8.5]), "NaN is not a finite number"),
])
def test_a_plan_with_a_null_radius_or_nan_is_refused(tmp_path, change, reason):
    doc = json.loads(PLAN.read_text())
    doc["geoFence"]["circles"] = [{"circle": {"center": [47.3986, 8.5469], "radius": 20}, "inclusion": False,
                                   "version": 1}]
    change(doc["geoFence"])
    path = tmp_path / "bad.plan"
    path.write_text(json.dumps(doc))  # json writes NaN as the literal NaN, which JSON does not have
    (line,) = _refused(companion("import", str(path), "--out", str(tmp_path / "m.yaml")))
    assert str(path) in line and reason in line, line
    assert not (tmp_path / "m.yaml").exists()


def test_validate_without_the_certificate_says_nothing_of_it():
    proc = companion("validate", str(REFERENCE), "--no-certificate")
    assert proc.returncode == 0 and "ok: 2 vehicle(s)" in proc.stdout and "certificate" not in proc.stdout


NO_NUMBA = ("import runpy, sys; sys.modules['numba'] = None; sys.argv[0] = 'companion'; "  # numba hidden: numpy alone
            "runpy.run_module('companion', run_name='__main__')")
HAS_NUMBA = importlib.util.find_spec("numba") is not None


@pytest.mark.slow
@pytest.mark.parametrize("path", [
    pytest.param("compiled", marks=[pytest.mark.extra, pytest.mark.skipif(
        not HAS_NUMBA, reason="needs the fast extra (numba): pip install -e '.[fast]'")]),
    "numpy",
])
def test_a_mission_at_the_schema_limits_validates_within_its_budget(tmp_path, path):
    """200 polygons of 256 vertices, on the compiled kernels and on numpy alone (numba hidden): the
    certificate stops within its CPU budget, said so, and validate ends well inside the 30 s goal
    of CPU (wall is not bounded tighter than the test's own timeout: the suite runs under load)."""
    spec = importlib.util.spec_from_file_location("bench_validate", ROOT / "benchmarks" / "bench_validate.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    mission = tmp_path / "limits.yaml"
    mission.write_text(bench.sized_mission(200, 256))
    head = ["-m", "companion"] if path == "compiled" else ["-c", NO_NUMBA]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, *head, "validate", str(mission), "--certificate-budget", "5"],
                          capture_output=True, text=True, timeout=240, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert "ok: 2 vehicle(s), 200 obstacle(s)" in proc.stdout
    assert "  whole flight: undecided within budget" in proc.stdout
    assert "  at closest approach: undecided within budget" in proc.stdout
    assert cpu_s < 20.0, f"{cpu_s:.1f} CPU s for a 5 s certificate budget"
