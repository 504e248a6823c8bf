"""The ``sitl`` fixture's side: a ``sim-bridge`` process on free ports, and the GCS recorder hearing it."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import Mission, load_mission
from companion.testing.processes import Processes
from companion.testing.telemetry import BackgroundRecorder, Telemetry
from sim_bridge.testing import bind_udp_port_block

# What a telemetry freeze stops on the API link: every position source (heartbeats, attitude go on).
POSITION_STREAMS = (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT)


class Sitl(Telemetry):
    """A running ``sim-bridge`` process and the GCS recorder listening to it."""

    def __init__(self, mission: Mission, mission_path: Path, recorder: BackgroundRecorder, *,
                 process: subprocess.Popen, api_port_base: int, api_addresses: dict[int, tuple],
                 speedup: float, log_path: Path):
        super().__init__(mission, mission_path, recorder)
        self.process = process
        self.api_port_base = api_port_base
        self.speedup = speedup
        self.log_path = log_path
        self._api_addresses = api_addresses  # system id -> the stub's API socket for that vehicle

    def connect_args(self) -> list[str]:
        """``--connect name=udpin://...`` arguments for ``companion run`` / ``upload``."""
        args: list[str] = []
        for v in self.mission.vehicles:
            args += ["--connect", f"{v.name}=udpin://127.0.0.1:{self.api_port_base + v.index}"]
        return args

    def companion_args(self) -> list[str]:
        """What ``companion run`` needs to fly these vehicles: one stub, one clock for every
        vehicle and the obstacles, so score on it."""
        return [*self.connect_args(), "--shared-clock"]

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace")

    # -- a telemetry freeze -------------------------------------------------------------------
    def freeze_position(self, name: str) -> None:
        """Stop vehicle ``name``'s position streams on its API link (what the companion reads);
        heartbeats, attitude (the vehicle clock) and the GCS link go on. PX4 does the same when
        anyone on the link asks for it with SET_MESSAGE_INTERVAL -1, which is how this works."""
        self._set_api_interval(name, -1.0)

    def resume_position(self, name: str) -> None:
        """Undo :meth:`freeze_position`: the position streams return to their default rates."""
        self._set_api_interval(name, 0.0)

    def _set_api_interval(self, name: str, interval_us: float) -> None:
        sysid = self.mission.vehicle(name).system_id
        for msg_id in POSITION_STREAMS:
            result = self.telemetry.call(self.recorder.command_via_tap(
                sysid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us))
            if result != mavlink.MAV_RESULT_ACCEPTED:
                raise AssertionError(f"vehicle {name!r} refused SET_MESSAGE_INTERVAL({msg_id}, {interval_us:g}): "
                                     f"result {result}")


class SitlFactory:
    """What the ``sitl`` fixture returns: call it to start a stub; every stub it started stops at teardown."""

    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._procs = Processes()
        self._running: list[Sitl] = []
        self._recorders: list[BackgroundRecorder] = []

    def __call__(self, mission_path: str | os.PathLike, *, speedup: float = 20.0, loss: float = 0.0,
                 latency_ms: float = 0.0, blackout: str | Sequence[str] = (), seed: int = 1,
                 extra: Sequence[str] = (), ready_timeout_s: float = 20.0) -> Sitl:
        """Start ``sim-bridge`` for the mission on free ports; return once every vehicle is heard.

        ``loss``, ``latency_ms`` and ``blackout`` (``"START:DURATION"`` in sim seconds, one or a
        list) are faults on the vehicles' API links; the GCS link the recorder hears stays clean.
        """
        mission_path = Path(mission_path)
        mission = load_mission(mission_path)
        recorder = BackgroundRecorder(port=0)
        self._recorders.append(recorder)
        api_socks = bind_udp_port_block(len(mission.vehicles))  # held until the stub is heard on them
        try:
            api_base = api_socks[0].getsockname()[1]
            log_path = self._tmp / f"sim_bridge{len(self._running)}.log"
            cmd = [sys.executable, "-m", "sim_bridge", str(mission_path), "--speedup", f"{speedup:g}",
                   "--gcs-port", str(recorder.port), "--api-port-base", str(api_base), "--seed", str(seed)]
            if loss:
                cmd += ["--loss", f"{loss:g}"]
            if latency_ms:
                cmd += ["--latency-ms", f"{latency_ms:g}"]
            for b in [blackout] if isinstance(blackout, str) else blackout:
                cmd += ["--blackout", b]
            cmd += list(extra)
            with open(log_path, "wb") as log:
                proc, _ = self._procs.spawn(cmd, stdout=log, stderr=subprocess.STDOUT)
            addresses = self._api_addresses(api_socks, mission, proc, log_path, ready_timeout_s)
        finally:
            for s in api_socks:
                s.close()
        sitl = Sitl(mission, mission_path, recorder, process=proc, api_port_base=api_base,
                    api_addresses=addresses, speedup=speedup, log_path=log_path)
        self._running.append(sitl)
        ids = [v.system_id for v in mission.vehicles]
        try:
            recorder.wait_until(lambda r: all(r.heard(i) for i in ids), timeout_s=ready_timeout_s,
                                what=f"heartbeats from systems {ids} on the GCS link")
            for v in mission.vehicles:  # dense positions from the API link as well (see TelemetryRecorder)
                recorder.call(recorder.recorder.tap(v.system_id, addresses[v.system_id], timeout_s=ready_timeout_s),
                              ready_timeout_s)
        except TimeoutError as exc:
            raise AssertionError(f"sim-bridge: {exc}\n{log_path.read_text(errors='replace')[-2000:]}") from None
        return sitl

    @staticmethod
    def _api_addresses(socks: list[socket.socket], mission: Mission, proc: subprocess.Popen, log_path: Path,
                       timeout_s: float) -> dict[int, tuple]:
        """Where each vehicle's API datagrams come from (the stub sends first, PX4 SITL style)."""
        out: dict[int, tuple] = {}
        deadline = time.monotonic() + timeout_s
        for v, s in zip(mission.vehicles, socks):
            s.settimeout(0.2)
            while v.system_id not in out:
                if proc.poll() is not None or time.monotonic() > deadline:
                    why = f"exited with {proc.returncode}" if proc.poll() is not None else \
                        f"sent nothing to port {s.getsockname()[1]} in {timeout_s:g} s"
                    raise AssertionError(f"sim-bridge {why}:\n{log_path.read_text(errors='replace')[-2000:]}")
                try:
                    _, addr = s.recvfrom(65535)
                except TimeoutError:
                    continue
                out[v.system_id] = addr
        return out

    def close(self) -> None:
        self._procs.close(*self._recorders)
