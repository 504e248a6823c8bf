"""Whole missions on real PX4 SITL: the reference beside ``simulate --plant multicopter``, and the
small reference flown twice on the same PX4 instances."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from companion.cli.options import with_plant
from companion.planning.flight.headless import simulate
from uav_model.mission import load_mission


ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"
SMALL = ROOT / "missions" / "small_reference.yaml"
SPEEDUP = 4.0  # PX4 SIH's speed factor in this tier: PX4 scales its loss timeouts with it

pytestmark = [pytest.mark.px4, pytest.mark.slow]
# The occlusion certificate (pre-flight numpy, 20 CPU s by default) is not read here: skipped to keep the tier short.
NO_CERTIFICATE = "--no-certificate"


@pytest.mark.timeout(600)
def test_the_reference_on_px4_flies_within_5_percent_of_the_multicopter_simulation(px4, companion, tmp_path):
    # `companion run --sim px4`: the companion starts PX4 itself, flies, and stops it.
    out = tmp_path / "run"
    result = companion.cli("run", REFERENCE, "--sim", "px4", "--px4-dir", px4.px4_dir, "--speedup", f"{SPEEDUP:g}",
                           NO_CERTIFICATE, "--out", out, timeout_s=540)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"], summary["reason"]
    headless = simulate(with_plant(load_mission(REFERENCE), "multicopter")).summary
    for name, v in headless.vehicles.items():
        flown = summary["vehicles"][name]["flight_time_s"]
        assert flown == pytest.approx(v.flight_time_s, rel=0.05), (name, flown, v.flight_time_s)
    for name in ("a", "b"):
        log = (out / f"px4-{name}.log").read_text()
        assert "Startup script returned successfully" in log and "PX4 Exiting" in log  # started and stopped


@pytest.mark.timeout(600)
def test_the_small_reference_then_a_second_run_on_the_same_px4(px4, companion, tmp_path):
    fleet = px4(SMALL, speedup=SPEEDUP)
    first = companion(fleet, NO_CERTIFICATE, timeout_s=300)
    assert first.exit_code == 0, first.tail
    assert first.summary["success"], first.summary["reason"]
    fleet.assert_arrived()
    fleet.assert_clearance()
    fleet.assert_separation()
    armed_before = {n: fleet.vehicle(n).armed_history.count(True) for n in ("a", "b")}

    # Both vehicles now stand at the other station: the same mission is refused, nothing arms.
    again = companion(fleet, NO_CERTIFICATE, timeout_s=120)
    assert again.exit_code == 2, again.tail
    err = again.stderr.strip().splitlines()
    assert len(err) == 1 and "from station" in err[0] and "--plan-from-current" in err[0], err
    assert "nothing was armed" in err[0]
    assert {n: fleet.vehicle(n).armed_history.count(True) for n in ("a", "b")} == armed_before

    # The way back, from where they stand: PX4 re-arms after its own landing and disarm.
    back = companion(fleet, NO_CERTIFICATE, "--plan-from-current", mission=_swapped(SMALL, tmp_path), timeout_s=300)
    assert back.exit_code == 0, back.tail
    assert back.summary["success"], back.summary["reason"]
    for name in ("a", "b"):
        assert fleet.vehicle(name).armed_history.count(True) == armed_before[name] + 1


def _swapped(path: Path, tmp_path: Path) -> Path:
    """``path`` flown back: every vehicle from its goal to its start, heading turned round."""
    doc = yaml.safe_load(path.read_text())
    doc["name"] = f"{doc['name']}_back"
    for v in doc["vehicles"]:
        v["start"], v["goal"] = v["goal"], v["start"]
        v["initial_heading_deg"] = (v.get("initial_heading_deg", 0.0) + 360.0) % 360.0 - 180.0
    out = tmp_path / f"{doc['name']}.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out
