"""pytest plugin: telemetry-driven scenario tests against the SITL stub and the companion.

Installed with the package (entry point ``pytest11: astar_bdwa``), it provides two fixtures:

``sitl``
    A factory: ``sitl(mission_path, speedup=20, loss=0.0, latency_ms=0.0, extra=())`` starts
    ``sim-bridge`` for the mission on free UDP ports, with a GCS-side :class:`TelemetryRecorder`
    already listening, and returns a :class:`Sitl` once every vehicle's heartbeat is heard.
``companion``
    A factory: ``companion(sitl, "--variant", "dwa", timeout_s=120)`` runs ``companion run``
    against that stub (``--connect`` to each vehicle) and returns a :class:`CompanionRun`;
    ``companion.start(sitl)`` returns the live process instead (to kill it mid-flight).

Every process is started in its own session and killed with its group at teardown, pass or
fail, so no orphan survives a test. Assertions read the *vehicles' own telemetry*:
``sitl.report()`` scores the recorded tracks with the same :mod:`companion.planning.metrics`
code that ``companion simulate`` uses.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from companion.frames import local_to_geodetic
from companion.mission import Mission, load_mission
from companion.planning.metrics import RunSummary, summarize
from companion.testing.recorder import TelemetryRecorder, VehicleLog


def free_udp_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_udp_port_block(count: int, host: str = "127.0.0.1") -> int:
    """A base port with ``count`` consecutive free UDP ports (vehicle i listens on base + i)."""
    for _ in range(200):
        base = free_udp_port(host)
        if base + count > 65535:
            continue
        socks = []
        try:
            for i in range(count):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind((host, base + i))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no block of free UDP ports found")


class BackgroundRecorder:
    """A :class:`TelemetryRecorder` on its own event loop in a daemon thread, for sync tests."""

    def __init__(self, port: int = 0):
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="telemetry-recorder", daemon=True)
        self._thread.start()
        self.recorder = TelemetryRecorder(port=port)
        self._call(self.recorder.__aenter__())
        self.port = self.recorder.port

    def _call(self, coro, timeout_s: float = 30.0):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout_s + 1.0)

    def wait_until(self, predicate: Callable[[TelemetryRecorder], bool], *, timeout_s: float, what: str) -> None:
        self._call(self.recorder.wait_until(predicate, timeout_s=timeout_s, what=what), timeout_s)

    def download_mission(self, system_id: int, timeout_s: float = 10.0):
        return self._call(self.recorder.download_mission(system_id, timeout_s=timeout_s), timeout_s)

    def close(self) -> None:
        if self._loop.is_closed():
            return
        try:
            self._call(self.recorder.__aexit__(None, None, None), 5.0)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
            self._loop.close()


def _kill_group(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(grace_s)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(5.0)


@dataclass
class Sitl:
    """A running stub: its mission, ports, process and the GCS recorder listening to it."""

    mission: Mission
    mission_path: Path
    api_port_base: int
    gcs_port: int
    speedup: float
    process: subprocess.Popen
    telemetry: BackgroundRecorder
    log_path: Path

    @property
    def recorder(self) -> TelemetryRecorder:
        return self.telemetry.recorder

    def connect_args(self) -> list[str]:
        """``--connect name=udpin://...`` arguments for ``companion run`` / ``upload``."""
        args: list[str] = []
        for v in self.mission.vehicles:
            args += ["--connect", f"{v.name}=udpin://127.0.0.1:{self.api_port_base + v.index}"]
        return args

    def vehicle(self, name: str) -> VehicleLog:
        return self.recorder.log(self.mission.vehicle(name).system_id)

    def modes(self, name: str) -> list[str]:
        """The flight-mode sequence the vehicle reported (consecutive repeats folded)."""
        return list(self.vehicle(name).modes)

    def wait_for_mode(self, name: str, mode: str, timeout_s: float = 30.0) -> None:
        sysid = self.mission.vehicle(name).system_id
        self.telemetry.wait_until(lambda r: r.heard(sysid) and r.log(sysid).last_mode == mode,
                                  timeout_s=timeout_s, what=f"vehicle {name!r} in {mode}")

    def report(self, since_mode: str | None = "OFFBOARD") -> RunSummary:
        """SPEC §2 success and metrics, from the recorded telemetry tracks.

        Tracks start when each vehicle first enters ``since_mode`` (departure), so flight times
        compare with ``companion simulate``; ``None`` scores everything recorded.
        """
        tracks = {v.name: self.vehicle(v.name).track(since_mode) for v in self.mission.vehicles
                  if self.recorder.heard(v.system_id) and self.vehicle(v.name).t_s}
        return summarize(self.mission, tracks)

    def mission_on_vehicle(self, name: str) -> list[tuple[float, float]]:
        """The waypoints stored on the vehicle, as (lat_deg, lon_deg), downloaded as a GCS would."""
        rows = self.telemetry.download_mission(self.mission.vehicle(name).system_id)
        return [(lat, lon) for _, lat, lon, _ in rows]

    def plan_as_geodetic(self, waypoints_enu: Sequence[Sequence[float]]) -> list[tuple[float, float]]:
        return [local_to_geodetic(self.mission.origin, float(x), float(y))[:2] for x, y in waypoints_enu]


@dataclass
class CompanionRun:
    exit_code: int
    stdout: str
    stderr: str
    out_dir: Path

    @property
    def summary(self) -> dict:
        return json.loads((self.out_dir / "summary.json").read_text())


class _CompanionFactory:
    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._procs: list[subprocess.Popen] = []

    def start(self, sitl: Sitl, *args: str, out_dir: Path | None = None) -> subprocess.Popen:
        out_dir = out_dir or self._tmp / "companion"
        cmd = [sys.executable, "-m", "companion", "run", str(sitl.mission_path), *sitl.connect_args(),
               "--out", str(out_dir), *args]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        self._procs.append(proc)
        return proc

    def __call__(self, sitl: Sitl, *args: str, timeout_s: float = 180.0) -> CompanionRun:
        out_dir = self._tmp / f"companion{len(self._procs)}"
        proc = self.start(sitl, *args, out_dir=out_dir)
        try:
            stdout, stderr = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            stdout, stderr = proc.communicate()
            raise AssertionError(f"companion run did not finish in {timeout_s:g} s\n{stderr[-2000:]}") from None
        return CompanionRun(proc.returncode, stdout, stderr, out_dir)

    def close(self) -> None:
        for p in self._procs:
            _kill_group(p)


class _SitlFactory:
    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._running: list[Sitl] = []

    def __call__(self, mission_path: str | os.PathLike, *, speedup: float = 20.0, loss: float = 0.0,
                 latency_ms: float = 0.0, seed: int = 1, extra: Sequence[str] = (),
                 ready_timeout_s: float = 20.0) -> Sitl:
        mission_path = Path(mission_path)
        mission = load_mission(mission_path)
        telemetry = BackgroundRecorder(port=0)
        api_base = free_udp_port_block(len(mission.vehicles))
        log_path = self._tmp / f"sim_bridge{len(self._running)}.log"
        cmd = [sys.executable, "-m", "sim_bridge", str(mission_path), "--speedup", str(speedup),
               "--gcs-port", str(telemetry.port), "--api-port-base", str(api_base),
               "--seed", str(seed), *extra]
        if loss:
            cmd += ["--loss", str(loss)]
        if latency_ms:
            cmd += ["--latency-ms", str(latency_ms)]
        log = open(log_path, "w")
        try:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        finally:
            log.close()
        sitl = Sitl(mission, mission_path, api_base, telemetry.port, speedup, proc, telemetry, log_path)
        self._running.append(sitl)
        ids = [v.system_id for v in mission.vehicles]
        try:
            telemetry.wait_until(lambda r: all(r.heard(i) for i in ids), timeout_s=ready_timeout_s,
                                 what=f"heartbeats from systems {ids}")
        except TimeoutError:
            raise AssertionError(f"sim-bridge did not come up: {log_path.read_text()[-2000:]}") from None
        return sitl

    def close(self) -> None:
        for s in self._running:
            _kill_group(s.process)
            s.telemetry.close()


@pytest.fixture
def sitl(tmp_path: Path) -> Iterator[_SitlFactory]:
    """Start the SITL stub for a mission on free ports: ``stub = sitl("missions/x.yaml")``."""
    factory = _SitlFactory(tmp_path)
    try:
        yield factory
    finally:
        factory.close()


@pytest.fixture
def companion(tmp_path: Path) -> Iterator[_CompanionFactory]:
    """Run the companion against a stub: ``run = companion(stub)``; ``companion.start(stub)``."""
    factory = _CompanionFactory(tmp_path)
    try:
        yield factory
    finally:
        factory.close()

