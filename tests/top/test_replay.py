"""``companion replay``: a flown run (in process, no sockets) renders as an animated GIF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from companion.cli import main

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def _frames(path: Path) -> list[np.ndarray]:
    out = []
    with Image.open(path) as im:
        for k in range(im.n_frames):
            im.seek(k)
            out.append(np.asarray(im.convert("RGB")))
    return out


@pytest.mark.parametrize("mission", ["paper_reference.yaml", "moving_obstacles.yaml"])
def test_a_flown_run_replays_as_a_gif(tmp_path, capsys, companion_logger, mission):
    out = tmp_path / "run"
    main(["run", str(ROOT / "missions" / mission), "--in-process", "--out", str(out)])
    assert (out / "flight.csv").exists()
    assert main(["replay", str(out), "--fps", "4", "--seconds", "1.5"]) == 0  # the mission from summary.json
    frames = _frames(out / "replay.gif")
    assert len(frames) == 6
    assert frames[0].shape[0] > 400 and frames[0].shape[1] > 400
    # The vehicles move: first and last frames differ well beyond the clock's digits.
    assert np.mean(np.any(frames[0] != frames[-1], axis=2)) > 0.002


def test_replay_refuses_a_directory_without_a_flight_in_one_line(tmp_path, capsys):
    assert main(["replay", str(tmp_path), "--mission", str(ROOT / "missions" / "paper_reference.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "flight.csv: not found" in err and "\n" not in err
