"""The ``px4`` fixture's side: real PX4 SITL (SIH) for a mission, and the GCS recorder hearing it.

PX4 comes from ``--px4-dir`` (a pytest option) or ``PX4_SITL_DIR``; without either, a test that
asks for it is skipped with a reason that says so. PX4 SITL's ports are fixed (API link to 14540
+ i, GCS link to 14550) and it keeps a lock per instance number in /tmp, so one fleet runs at a
time on a machine: the fixture takes a file lock for the whole test (pytest-xdist workers wait
for each other), and the tier is best run in its own network and mount namespace.
"""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest

from companion.cli_common import BadInput
from companion.planning.metrics import Track
from companion.sitl.px4 import API_PORT_BASE, GCS_PORT, PX4_DIR_ENV, Px4Fleet, Px4Options, find_px4
from companion.testing.telemetry import BackgroundRecorder, Telemetry
from uav_model.mission import Mission, load_mission

SKIP_REASON = (f"PX4 SITL not found: set {PX4_DIR_ENV}=DIR or pass --px4-dir DIR (a PX4 SITL build with bin/px4 "
               f"and etc/, e.g. {PX4_DIR_ENV}=../shared/px4-sih/sitl)")
LOCK_PATH = Path(tempfile.gettempdir()) / "astar-bdwa-px4-tier.lock"


def px4_dir_or_skip(config: pytest.Config) -> Path:
    """The PX4 SITL directory the session was given; skip when none was, fail when it is wrong."""
    given = config.getoption("px4_dir", default=None)
    if given is None and not os.environ.get(PX4_DIR_ENV):
        pytest.skip(SKIP_REASON)
    try:
        return find_px4(given)
    except BadInput as exc:
        pytest.fail(str(exc), pytrace=False)


class Px4Sitl(Telemetry):
    """PX4 SIH instances flying a mission's vehicles and the GCS recorder on port 14550.

    PX4's LOCAL_POSITION_NED is relative to each vehicle's own home (its start station), so the
    tracks here are shifted by that station into the mission's frame.
    """

    def __init__(self, mission: Mission, mission_path: Path, recorder: BackgroundRecorder, fleet: Px4Fleet):
        super().__init__(mission, mission_path, recorder)
        self.fleet = fleet
        # Where the companion listens for vehicle i (+ i): PX4's own ports, or a relay's
        # (companion.testing.relay.UplinkCut) put between them.
        self.listen_port_base = API_PORT_BASE

    @property
    def speedup(self) -> float:
        return self.fleet.options.speedup

    def connect_args(self) -> list[str]:
        """``--connect name=udpin://127.0.0.1:PORT`` arguments for ``companion run`` / ``upload``
        (PORT: ``listen_port_base`` + i)."""
        return [arg for v in self.mission.vehicles
                for arg in ("--connect", f"{v.name}=udpin://127.0.0.1:{self.listen_port_base + v.index}")]

    def loss_timeout_s(self, name: str) -> float:
        """Vehicle ``name``'s COM_OF_LOSS_T in sim seconds, as its startup script set it (PX4 SITL
        scales it with the speed factor)."""
        found = re.findall(r"COM_OF_LOSS_T: curr: [-\d.]+ -> new: ([-\d.]+)", self.log_text(name))
        if not found:
            raise AssertionError(f"vehicle {name!r}: no COM_OF_LOSS_T in its PX4 log")
        return float(found[-1])

    def companion_args(self) -> list[str]:
        """What ``companion run`` needs to fly these vehicles (each PX4 has its own clock)."""
        return self.connect_args()

    def log_text(self, name: str) -> str:
        """Vehicle ``name``'s PX4 console output so far."""
        return self.fleet.log_text(name)

    def track(self, name: str, since_mode: str | None = None) -> Track:
        tr = super().track(name, since_mode)
        x0, y0 = self.mission.vehicle(name).start_enu_m
        return Track(tr.t_s, np.asarray(tr.x_m) + x0, np.asarray(tr.y_m) + y0)


class Px4Factory:
    """What the ``px4`` fixture returns: ``fleet = px4("missions/x.yaml", speedup=4)``; teardown
    stops PX4 and the recorder. One fleet at a time (PX4's ports are fixed)."""

    def __init__(self, tmp_path: Path, px4_dir: Path):
        self._tmp = tmp_path
        self.px4_dir = px4_dir
        self._running: list[tuple[Px4Fleet, BackgroundRecorder]] = []
        self._lock = open(LOCK_PATH, "a+")
        fcntl.flock(self._lock, fcntl.LOCK_EX)  # released by close(), or by the OS if this process dies

    def __call__(self, mission_path: str | os.PathLike, *, speedup: float = 4.0,
                 params: Mapping[str, str] = {}, ready_timeout_s: float = 30.0) -> Px4Sitl:
        """Start one PX4 per vehicle at its station; return once every one is heard on the GCS
        link. ``params``: PX4 parameters set at boot (name -> value)."""
        if self._running:
            raise RuntimeError("one PX4 fleet per test: PX4 SITL's ports are fixed")
        mission_path = Path(mission_path)
        mission = load_mission(mission_path)
        recorder = BackgroundRecorder(port=GCS_PORT)
        fleet = Px4Fleet(mission, Px4Options(self.px4_dir, speedup=speedup, log_dir=self._tmp, params=dict(params),
                                             ready_timeout_s=ready_timeout_s), self._tmp / "px4-work")
        self._running.append((fleet, recorder))
        fleet.start()
        fleet.wait_ready()
        ids = [v.system_id for v in mission.vehicles]
        try:
            recorder.wait_until(lambda r: all(r.heard(i) for i in ids), timeout_s=ready_timeout_s,
                                what=f"heartbeats from systems {ids} on the GCS link (port {GCS_PORT})")
        except TimeoutError as exc:
            raise AssertionError(f"PX4: {exc}\n{fleet.log_text(mission.vehicles[0].name)[-2000:]}") from None
        return Px4Sitl(mission, mission_path, recorder, fleet)

    def close(self) -> None:
        try:
            for fleet, recorder in self._running:
                try:
                    fleet.stop()
                finally:
                    recorder.close()
        finally:
            self._lock.close()
