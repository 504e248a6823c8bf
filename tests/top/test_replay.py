"""``companion replay``: every flight log the product writes renders as an animated GIF, in the
trajectory plot's colours: in-process runs, a stopped ``--connect`` run with a telemetry stall
(event rows without a mission time), and a ``companion simulate`` directory."""

from __future__ import annotations

import csv
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from PIL import Image

from companion.cli import main
from companion.plots import vehicle_colors
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"

pytestmark = pytest.mark.slow


def _frames(path: Path) -> list[np.ndarray]:
    out = []
    with Image.open(path) as im:
        for k in range(im.n_frames):
            im.seek(k)
            out.append(np.asarray(im.convert("RGB")))
    return out


def _share_of(frame: np.ndarray, color: str) -> float:
    """The share of pixels within a few levels of ``color`` (the GIF palette rounds a little)."""
    rgb = np.array(to_rgb(color)) * 255
    return float(np.mean(np.all(np.abs(frame.astype(float) - rgb) <= 12, axis=2)))


def _replays(out: Path, *args: str) -> list[np.ndarray]:
    assert main(["replay", str(out), "--fps", "4", "--seconds", "1.5", *args]) == 0
    frames = _frames(out / "replay.gif")
    assert len(frames) == 6
    assert frames[0].shape[0] > 400 and frames[0].shape[1] > 400
    # The vehicles move: first and last frames differ well beyond the clock's digits.
    assert np.mean(np.any(frames[0] != frames[-1], axis=2)) > 0.002
    return frames


# A small-reference flight (the reference scaled by 0.2): with moving obstacles, moving_obstacles.yaml's
# truck and balloon scaled the same way. A fifth of the reference's flight to run for each.
SMALL_MOVING = """  - {id: truck, shape: circle, center: [200.0, 460.0], radius_m: 24.0,
     motion: {type: shuttle, to: [460.0, 200.0], speed_m_s: 4.0}}
  - {id: balloon, shape: circle, center: [520.0, 400.0], radius_m: 20.0,
     motion: {type: orbit, pivot: [460.0, 440.0], speed_m_s: 3.0}}
"""


@pytest.mark.parametrize("moving", [False, True], ids=["static", "moving"])
def test_a_flown_run_replays_as_a_gif(tmp_path, capsys, companion_logger, moving):
    mission = tmp_path / "small.yaml"
    text = SMALL.read_text()
    mission.write_text(text.replace("\nvehicles:", "\n" + SMALL_MOVING.rstrip("\n") + "\nvehicles:", 1) if moving else text)
    assert len(load_mission(mission).world.moving_obstacles) == (2 if moving else 0)
    out = tmp_path / "run"
    main(["run", str(mission), "--in-process", "--out", str(out)])
    assert (out / "flight.csv").exists()
    frames = _replays(out)  # the mission from summary.json
    # Each vehicle is drawn in its own colour, the one the trajectory plot gives it.
    for color in vehicle_colors(load_mission(mission)).values():
        assert _share_of(frames[-1], color) > 0.001, color


def test_a_simulate_directory_replays(tmp_path, capsys):
    out = tmp_path / "sim"
    main(["simulate", str(ROOT / "missions" / "moving_obstacles.yaml"), "--out", str(out)])
    frames = _replays(out)
    # The moving obstacles move: the middle frame differs from the first off the vehicles' trails.
    assert np.mean(np.any(frames[0] != frames[3], axis=2)) > 0.002


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _wait_for_row(path: Path, predicate, timeout_s: float) -> list[dict[str, str]]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        rows = _rows(path) if path.exists() else []
        if any(predicate(r) for r in rows):
            return rows
        time.sleep(0.2)
    raise AssertionError(f"{path}: no such row within {timeout_s} s")


def test_a_stopped_connect_run_with_a_telemetry_stall_replays(sitl, companion, tmp_path):
    """The stub's API link goes dark mid-flight (the companion hovers and logs a "stale" event row
    with no mission time), then the operator stops the run with Ctrl-C before the end."""
    # The stub's clock starts at its boot, the flight some time later on a loaded machine: a
    # 1 s (wall) blackout every 60 sim s, so that one falls early in the flight.
    stub = sitl(SMALL, speedup=20, blackout=[f"{t}:20" for t in range(60, 1200, 60)])
    live = companion.start(stub)  # --connect to the stub
    flight = live.out_dir / "flight.csv"
    rows = _wait_for_row(flight, lambda r: (r.get("note") or "").startswith("stale"), timeout_s=120)
    t_stale = max((float(r["t_mission_s"]) for r in rows if r.get("t_mission_s")), default=0.0)
    _wait_for_row(flight, lambda r: bool(r.get("t_mission_s")) and float(r["t_mission_s"]) > t_stale + 5.0, timeout_s=60)
    live.signal(signal.SIGINT)
    run = live.wait(60)
    assert not run.summary["success"], run.tail
    rows = _rows(flight)
    assert any(r["t_mission_s"] == "" for r in rows)  # the event rows that replay once tripped on
    assert not all(r["phase"] == "landed" for r in rows[-2:])  # stopped in flight
    _replays(live.out_dir)


def test_replay_refuses_a_directory_without_a_flight_in_one_line(tmp_path, capsys):
    assert main(["replay", str(tmp_path), "--mission", str(ROOT / "missions" / "paper_reference.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "flight.csv: not found" in err and "\n" not in err


def test_replay_refuses_a_log_of_another_mission_in_one_line(tmp_path, capsys):
    (tmp_path / "flight.csv").write_text("t_mission_s,t_sim_s,vehicle,x_m,y_m\n0.5,1.0,w1,0,0\n1.0,1.5,w1,5,0\n")
    assert main(["replay", str(tmp_path), "--mission", str(SMALL)]) == 2
    err = capsys.readouterr().err.strip()
    assert "['w1'] are not in mission" in err and "\n" not in err
