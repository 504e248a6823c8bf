"""The companion's geofence on real PX4: uploaded and read back, then breached in a companion flight
and reported by the companion as a fence event.

The breach is forced with a fence the companion uploaded for a smaller area (`companion upload`),
left on PX4 while `companion run --no-fence` flies the whole mission out of it: PX4 takes its own
geofence action (GF_ACTION) and says so, and the companion stands down with the reason
``geofence`` and the breach among its failsafes.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"
SPEEDUP = 4.0  # PX4 SIH's speed factor in this tier: PX4 scales its loss timeouts with it
NO_CERTIFICATE = "--no-certificate"  # pre-flight numpy (20 CPU s by default) this test does not read
FENCED_M = 300.0  # the smaller area's east and north edge; its fence (area + 100 m margin) ends at 400 m

pytestmark = [pytest.mark.px4, pytest.mark.slow, pytest.mark.timeout(420)]


def _solo(tmp_path: Path, area_max_m: float | None = None) -> Path:
    """The small reference with vehicle a alone (one PX4 is enough to judge its fence); with
    ``area_max_m``, inside that smaller area, station B at its corner."""
    doc = yaml.safe_load(SMALL.read_text())
    doc["vehicles"] = doc["vehicles"][:1]
    name = "small_reference_a"
    if area_max_m is not None:
        doc["area"].update(x_max_m=area_max_m, y_max_m=area_max_m)
        doc["stations"]["B"] = [area_max_m, area_max_m]
        name += "_fenced"
    doc["name"] = name
    out = tmp_path / f"{name}.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def test_a_breach_of_the_uploaded_fence_is_reported_by_the_companion_as_a_fence_event(px4, companion, tmp_path):
    mission = _solo(tmp_path)
    fleet = px4(mission, speedup=SPEEDUP)
    fenced = _solo(tmp_path, FENCED_M)
    upload = companion.cli("upload", fenced, *fleet.connect_args(), timeout_s=180)
    assert upload.returncode == 0, upload.stdout[-3000:] + upload.stderr
    assert "a: geofence uploaded and read back (the area and 1 obstacle" in upload.stdout, upload.stdout

    # The whole mission (B at 636 m, 636 m) flown with that fence left on PX4.
    run = companion(fleet, "--no-fence", NO_CERTIFICATE, timeout_s=300)
    assert run.exit_code == 1, run.tail
    summary = run.summary
    assert summary["reason"] == "geofence", (summary["reason"], summary["live"]["message"])
    fences = [e for e in summary["failsafes"] if e["cause"] == "geofence"]
    assert len(fences) == 1 and fences[0]["vehicle"] == "a" and not fences[0]["recovered"], summary["failsafes"]
    assert "geofence" in (fences[0]["notice"] or "").lower(), fences[0]  # PX4's own words, as heard
    assert fences[0]["mode"] != "OFFBOARD", fences[0]  # PX4 took over, and the companion let it
    assert "geofence breach" in run.stdout, run.tail

    # PX4's action stood: a stopped at the fence (400 m), not at B, and it did fly out to it.
    modes = [m for _, m in fleet.vehicle("a").mode_history()]
    assert "OFFBOARD" in modes and modes[-1] != "OFFBOARD", modes
    tr = fleet.track("a")
    reach = max(float(tr.x_m.max()), float(tr.y_m.max()))
    assert FENCED_M + 100.0 - 30.0 < reach < FENCED_M + 100.0 + 60.0, reach
