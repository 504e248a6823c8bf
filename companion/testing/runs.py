"""The ``companion`` fixture's side: ``companion run`` (or any ``companion`` command) as a process.

A run flies against a :class:`~companion.testing.stub.Sitl`, or against the companion's own
embedded stub, whose GCS link a recorder hears; either way ``run.telemetry`` is what a GCS heard.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from uav_model.mission import load_mission
from companion.testing.processes import Processes, signal_group
from companion.testing.px4 import Px4Sitl
from companion.testing.stub import Sitl
from companion.testing.telemetry import BackgroundRecorder, Telemetry
from sim_bridge.testing import free_udp_port_block


@dataclass
class CompanionRun:
    """A finished ``companion run``: exit code, output, its ``--out`` directory, and the telemetry."""

    exit_code: int
    stdout: str
    stderr: str
    out_dir: Path
    telemetry: Telemetry

    @property
    def summary(self) -> dict:
        """``summary.json`` (the companion's own account; prefer asserting on ``telemetry``)."""
        return json.loads((self.out_dir / "summary.json").read_text())

    def flight_log(self) -> list[dict[str, str]]:
        """``flight.csv``: one row per planner tick and per event."""
        return _csv_rows(self.out_dir / "flight.csv")

    def traffic_log(self) -> list[dict[str, str]]:
        """``traffic.csv``: the ADS-B reports the companion used."""
        return _csv_rows(self.out_dir / "traffic.csv")

    @property
    def tail(self) -> str:
        """The end of stdout and stderr, for assertion messages."""
        return f"exit {self.exit_code}\n--- stdout\n{self.stdout[-2500:]}\n--- stderr\n{self.stderr[-2500:]}"


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


class RunningCompanion:
    """A ``companion run`` still in flight (from ``companion.start``)."""

    def __init__(self, process: subprocess.Popen, tag: str, out_dir: Path, telemetry: Telemetry,
                 stdout_path: Path, stderr_path: Path):
        self.process = process
        self.out_dir = out_dir
        self.telemetry = telemetry
        self._tag = tag
        self._stdout_path, self._stderr_path = stdout_path, stderr_path

    @property
    def pid(self) -> int:
        return self.process.pid

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the companion (SIGKILL: to its whole process group, as a crash would)."""
        if sig == signal.SIGKILL:
            signal_group(self.process.pid, sig)
        else:
            self.process.send_signal(sig)

    def wait(self, timeout_s: float = 180.0) -> CompanionRun:
        """Wait for it to exit; AssertionError (with its output) if it does not in ``timeout_s``."""
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            signal_group(self.process.pid, signal.SIGKILL)
            self.process.wait(10.0)
            raise AssertionError(f"companion run did not finish in {timeout_s:g} s\n{self._result().tail}") from None
        return self._result()

    def survivors(self, timeout_s: float = 5.0) -> dict[int, str]:
        """Processes this run started that are still alive after waiting up to ``timeout_s``
        (e.g. an embedded stub, MAVSDK servers): pid -> command line. Empty is the goal."""
        deadline = time.monotonic() + timeout_s
        while (left := Processes.survivors(self._tag)) and time.monotonic() < deadline:
            time.sleep(0.05)
        return left

    def _result(self) -> CompanionRun:
        return CompanionRun(self.process.returncode, self._stdout_path.read_text(errors="replace"),
                            self._stderr_path.read_text(errors="replace"), self.out_dir, self.telemetry)


class CompanionFactory:
    """What the ``companion`` fixture returns: call it, or :meth:`start` or :meth:`cli`; teardown stops
    every process it started."""

    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._procs = Processes()
        self._count = 0
        self._recorders: list[BackgroundRecorder] = []

    def start(self, target: Sitl | Px4Sitl | str | os.PathLike, *args: str, mission: str | os.PathLike | None = None,
              speedup: float = 20.0) -> RunningCompanion:
        """Start ``companion run`` and return at once.

        ``target``: a :class:`Sitl` or :class:`Px4Sitl` to connect to, or a mission path to fly on the companion's
        embedded stub (at ``speedup``, on free ports, its GCS link recorded). ``mission``: fly
        this file instead of the stub's (e.g. a bad one). ``args`` go to ``companion run``.
        """
        n, self._count = self._count, self._count + 1
        out_dir = self._tmp / f"companion{n}"
        if isinstance(target, (Sitl, Px4Sitl)):
            telemetry: Telemetry = target
            link = target.companion_args()
        else:
            path = Path(target)
            recorder = BackgroundRecorder(port=0)
            self._recorders.append(recorder)
            telemetry = Telemetry(load_mission(path), path, recorder)
            link = ["--speedup", f"{speedup:g}", "--port-base", str(free_udp_port_block(len(telemetry.mission.vehicles))),
                    "--gcs-port", str(recorder.port)]
        cmd = [sys.executable, "-m", "companion", "run", str(mission or telemetry.mission_path), *link,
               "--out", str(out_dir), *args]
        stdout_path, stderr_path = self._tmp / f"companion{n}.stdout", self._tmp / f"companion{n}.stderr"
        with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
            proc, tag = self._procs.spawn(cmd, stdout=out, stderr=err)
        return RunningCompanion(proc, tag, out_dir, telemetry, stdout_path, stderr_path)

    def __call__(self, target: Sitl | Px4Sitl | str | os.PathLike, *args: str, timeout_s: float = 180.0,
                 mission: str | os.PathLike | None = None, speedup: float = 20.0) -> CompanionRun:
        """Run ``companion run`` to the end (see :meth:`start` for the arguments)."""
        return self.start(target, *args, mission=mission, speedup=speedup).wait(timeout_s)

    def cli(self, *args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
        """Any other ``companion`` command (``upload``, ``validate``...), run to the end."""
        n, self._count = self._count, self._count + 1
        stdout_path, stderr_path = self._tmp / f"companion{n}.stdout", self._tmp / f"companion{n}.stderr"
        cmd = [sys.executable, "-m", "companion", *map(str, args)]
        with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
            proc, _ = self._procs.spawn(cmd, stdout=out, stderr=err)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._procs.stop(proc)
            raise AssertionError(f"companion {' '.join(map(str, args))} did not finish in {timeout_s:g} s\n"
                                 f"{stdout_path.read_text(errors='replace')[-2000:]}") from None
        return subprocess.CompletedProcess(cmd, proc.returncode, stdout_path.read_text(errors="replace"),
                                           stderr_path.read_text(errors="replace"))

    def close(self) -> None:
        self._procs.close(*self._recorders)
