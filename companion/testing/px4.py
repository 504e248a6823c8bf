"""The ``px4`` fixture's side: real PX4 SITL (SIH) for a mission, and the GCS recorder hearing it.

PX4 comes from ``--px4-dir`` (a pytest option) or ``PX4_SITL_DIR``; without either, a test that
asks for it is skipped with a reason that says so. PX4 SITL's ports are fixed (API link to 14540
+ i, GCS link to 14550) and it keeps a lock per instance number in /tmp, so one fleet runs at a
time on a machine: the fixture takes a file lock for the whole test (pytest-xdist workers wait
for each other), and the tier is best run in its own network and mount namespace.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.cli.errors import BadInput
from companion.planning.metrics import Track
from companion.sitl.px4 import API_PORT_BASE, GCS_PORT, PX4_DIR_ENV, Px4Fleet, Px4Options, find_px4
from companion.testing.telemetry import BackgroundRecorder, Telemetry
from uav_model.mission import Mission, load_mission

SKIP_REASON = (f"PX4 SITL not found: set {PX4_DIR_ENV}=DIR or pass --px4-dir DIR (a PX4 SITL build with bin/px4 "
               f"and etc/, e.g. {PX4_DIR_ENV}=../shared/px4-sih/sitl)")
LOCK_PATH = Path(tempfile.gettempdir()) / "astar-bdwa-px4-tier.lock"
# PX4's GCS link streams attitude, targets and outputs at 50-100 Hz of sim time (400/s of wall
# time at 4x, per vehicle): more than a Python recorder parses on a busy machine, and what it
# drops includes STATUSTEXT. The recorder asks for what a test reads, as a GCS does.
GCS_STREAMS_HZ = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 0.0, mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 0.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: 0.0, mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 0.0,
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 0.0, mavlink.MAVLINK_MSG_ID_VFR_HUD: 0.0,
}


def command_long(system_id: int, command: int, *params: float) -> mavlink.MAVLink_command_long_message:
    """A COMMAND_LONG to autopilot ``system_id`` (params beyond those given are 0)."""
    p = [float(v) for v in params] + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(system_id, 1, command, 0, *p)


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
        """What ``companion run`` needs to fly these vehicles: their links, that each PX4 runs its
        own clock (instances booted together start with clocks the detection takes for one), and
        that they are multicopters (the planner's fence margins and tracking lag are the plant's)."""
        return [*self.connect_args(), "--no-shared-clock", "--plant", "multicopter"]

    def send(self, name: str, msg) -> None:
        """Send one MAVLink message to vehicle ``name`` on its GCS link (commands, setpoints...)."""
        sysid = self.mission.vehicle(name).system_id

        async def on_loop() -> None:
            self.recorder.send(sysid, msg)
        self.telemetry.call(on_loop())

    def command(self, name: str, command: int, *params: float) -> None:
        """A COMMAND_LONG to vehicle ``name`` on its GCS link (its answer is not awaited)."""
        self.send(name, command_long(self.mission.vehicle(name).system_id, command, *params))

    def calm_gcs_link(self) -> None:
        """Ask every vehicle for the GCS streams in GCS_STREAMS_HZ (0: off), twice: UDP."""
        for _ in range(2):
            for v in self.mission.vehicles:
                for msg_id, hz in GCS_STREAMS_HZ.items():
                    self.command(v.name, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz if hz else -1)

    def start_gcs_heartbeat(self) -> None:
        """Say hello as a GCS once a second (on the recorder's loop) until :meth:`stop_gcs_heartbeat`:
        PX4 sends STATUSTEXT on its GCS link only once it has heard a GCS there."""
        hello = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                  mavlink.MAV_STATE_ACTIVE, 3)
        ids = [v.system_id for v in self.mission.vehicles]

        async def beat() -> None:
            while True:
                for sysid in ids:
                    self.recorder.send(sysid, hello)
                await asyncio.sleep(1.0)

        async def start() -> asyncio.Task:
            return asyncio.get_running_loop().create_task(beat(), name="gcs-heartbeat")
        self._heartbeat = self.telemetry.call(start())

    def stop_gcs_heartbeat(self) -> None:
        task = getattr(self, "_heartbeat", None)
        if task is None:
            return

        async def stop() -> None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        self.telemetry.call(stop())
        self._heartbeat = None

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
        self._sitls: list[Px4Sitl] = []
        self._lock = open(LOCK_PATH, "a+")
        fcntl.flock(self._lock, fcntl.LOCK_EX)  # released by close(), or by the OS if this process dies

    def __call__(self, mission_path: str | os.PathLike, *, speedup: float = 4.0,
                 params: Mapping[str, str] = {}, ready_timeout_s: float = 90.0) -> Px4Sitl:
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
        sitl = Px4Sitl(mission, mission_path, recorder, fleet)
        sitl.calm_gcs_link()
        sitl.start_gcs_heartbeat()
        self._sitls.append(sitl)
        return sitl

    def close(self) -> None:
        try:
            for fleet, recorder in self._running:
                try:
                    for sitl in self._sitls:
                        if sitl.fleet is fleet:
                            sitl.stop_gcs_heartbeat()
                finally:
                    try:
                        fleet.stop()
                    finally:
                        recorder.close()
        finally:
            self._lock.close()
