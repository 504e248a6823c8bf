"""pytest plugin: telemetry-driven scenario tests against the SITL stub and the companion.

Installed with the package (entry point ``pytest11: astar_bdwa``); docs/testing.md is the guide.
Two fixtures, both factories:

``sitl(mission_path, speedup=20, loss=0, latency_ms=0, blackout=(), seed=1, extra=())``
    starts ``sim-bridge`` for the mission on free UDP ports with a GCS-side recorder already
    listening, and returns a :class:`Sitl` once every vehicle is heard on both links.
``companion(target, *args, timeout_s=180)``
    runs ``companion run`` to the end and returns a :class:`CompanionRun`. ``target`` is a
    :class:`Sitl` (the companion connects to it) or a mission path (the companion starts its
    embedded stub, whose GCS link the recorder hears: ``run.telemetry``).
    ``companion.start(...)`` returns a :class:`RunningCompanion` instead, to signal mid-flight.

Assertions read the vehicles' own telemetry as a GCS hears it (:class:`Telemetry`): arrival,
separation, clearance to the mission's TRUE obstacles, geofence, the mode sequence, the mission
stored on each vehicle, and :meth:`Telemetry.report` (SPEC §2 metrics from the shared
:mod:`companion.planning.metrics`, LOS metrics included).

Every process is started in its own session with a tag in its environment, which its children
inherit. Teardown, pass or fail, stops each process group (SIGTERM, then SIGKILL) and then every
tagged process left, so no orphan (MAVSDK servers, an embedded stub) outlives a test.
"""

from __future__ import annotations

import asyncio
import csv
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pytest
import shapely
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import geodetic_to_local
from uav_model.mission import Mission, load_mission
from companion.planning.metrics import RunSummary, Track, TruthGeometry, arrival, inside_fence, \
    pair_min_distance, summarize
from companion.testing.recorder import GCS_COMPONENT_ID, GCS_SYSTEM_ID, TelemetryRecorder, VehicleLog
from companion.vehicle.port import GeoWaypoint
from sim_bridge.testing import bind_udp_port_block, free_udp_port_block

HARNESS_ENV = "ASTAR_BDWA_HARNESS"  # tag in the environment of every process the fixtures start
# What a telemetry freeze stops on the API link: every position source (heartbeats, attitude go on).
POSITION_STREAMS = (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT)


# =========================================================================== ports ==========

def free_udp_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


# =========================================================================== processes ======

def _tagged_processes(prefix: str) -> dict[int, str]:
    """Live processes whose environment carries ``HARNESS_ENV=<prefix>...`` (pid -> command line)."""
    needle = f"\0{HARNESS_ENV}={prefix}".encode()
    found: dict[int, str] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:  # no procfs: process groups are all we can rely on
        return found
    for entry in entries:
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                env = b"\0" + f.read()
            if needle not in env:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                found[int(entry)] = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return found


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class _Processes:
    """The processes one fixture started; each tagged so that its descendants are found too."""

    def __init__(self) -> None:
        self._prefix = f"{uuid.uuid4().hex[:12]}-"
        self._procs: list[tuple[subprocess.Popen, str]] = []

    def spawn(self, cmd: Sequence[str], stdout, stderr) -> tuple[subprocess.Popen, str]:
        tag = f"{self._prefix}{len(self._procs)}"
        proc = subprocess.Popen(list(cmd), stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr,
                                start_new_session=True, env={**os.environ, HARNESS_ENV: tag})
        self._procs.append((proc, tag))
        return proc, tag

    @staticmethod
    def survivors(tag: str) -> dict[int, str]:
        """Processes still alive from one spawn (the process itself and all it started)."""
        return {pid: cmd for pid, cmd in _tagged_processes(tag).items()
                if _tagged_tag(pid) == tag}

    def stop(self, proc: subprocess.Popen, grace_s: float = 5.0) -> None:
        """SIGTERM the process group, SIGKILL it after ``grace_s``. Always reaps."""
        if proc.poll() is None:
            _signal_group(proc.pid, signal.SIGTERM)
            try:
                proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                pass
        _signal_group(proc.pid, signal.SIGKILL)  # members may outlive a leader that exited
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            pass

    def close(self) -> None:
        for proc, _ in reversed(self._procs):  # the companion before the stub it flies
            self.stop(proc)
        deadline = time.monotonic() + 5.0
        while (left := _tagged_processes(self._prefix)) and time.monotonic() < deadline:
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
            time.sleep(0.05)
        if left:
            raise RuntimeError(f"processes survived SIGKILL: {left}")


def _tagged_tag(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            for item in f.read().split(b"\0"):
                if item.startswith(f"{HARNESS_ENV}=".encode()):
                    return item.split(b"=", 1)[1].decode()
    except OSError:
        return None
    return None


# =========================================================================== recorder =======

class BackgroundRecorder:
    """A :class:`TelemetryRecorder` on its own event loop in a daemon thread, for sync tests."""

    def __init__(self, port: int = 0):
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="telemetry-recorder", daemon=True)
        self._thread.start()
        self.recorder = TelemetryRecorder(port=port)
        self.call(self.recorder.__aenter__())
        self.port = self.recorder.port

    def call(self, coro, timeout_s: float = 30.0):
        """Run a coroutine of the recorder on its loop and return its result."""
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout_s + 1.0)

    def wait_until(self, predicate: Callable[[TelemetryRecorder], bool], *, timeout_s: float, what: str) -> None:
        self.call(self.recorder.wait_until(predicate, timeout_s=timeout_s, what=what), timeout_s)

    def download_mission(self, system_id: int, timeout_s: float = 10.0):
        return self.call(self.recorder.download_mission(system_id, timeout_s=timeout_s), timeout_s)

    def close(self) -> None:
        if self._loop.is_closed():
            return
        try:
            self.call(self.recorder.__aexit__(None, None, None), 5.0)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
            self._loop.close()


# =========================================================================== telemetry ======

@dataclass(frozen=True)
class TrafficSample:
    """An ADS-B report heard from a vehicle, in the mission's ENU frame at the vehicle's sim time."""

    t_s: float
    callsign: str
    x_m: float
    y_m: float
    course_deg: float
    speed_m_s: float


class Telemetry:
    """What a GCS heard from the mission's vehicles, with the assertions a scenario test makes.

    Vehicles are named as in the mission file. Times are the vehicle's sim time (s since the
    stub started), which is also the clock the mission's moving obstacles follow.
    """

    def __init__(self, mission: Mission, mission_path: Path, recorder: BackgroundRecorder):
        self.mission = mission
        self.mission_path = mission_path
        self.telemetry = recorder
        self._plans: dict[str | None, object] = {}

    @property
    def recorder(self) -> TelemetryRecorder:
        return self.telemetry.recorder

    @property
    def gcs_port(self) -> int:
        return self.telemetry.port

    # -- raw access ---------------------------------------------------------------------------
    def vehicle(self, name: str) -> VehicleLog:
        """Everything vehicle ``name`` reported (positions, modes, STATUSTEXT, ADS-B...)."""
        sysid = self.mission.vehicle(name).system_id
        if not self.recorder.heard(sysid):
            raise AssertionError(f"vehicle {name!r} (system {sysid}) was never heard on the GCS link")
        return self.recorder.log(sysid)

    def modes(self, name: str) -> list[str]:
        """The flight-mode sequence vehicle ``name`` reported, initial mode first, repeats folded."""
        return self.vehicle(name).modes

    def mode_times(self, name: str, mode: str) -> list[float]:
        """Sim times at which vehicle ``name`` entered ``mode``."""
        return [t for t, m in self.vehicle(name).mode_history() if m == mode]

    def clock_s(self, name: str) -> float:
        """Vehicle ``name``'s latest sim time."""
        return self.vehicle(name).clock_s or 0.0

    def track(self, name: str, since_mode: str | None = None) -> Track:
        """Vehicle ``name``'s ENU ground track; ``since_mode="OFFBOARD"`` starts it at departure."""
        return self.vehicle(name).track(since_mode)

    def traffic(self, name: str | None = None) -> dict[str, list[TrafficSample]]:
        """ADS-B reports heard from vehicle ``name`` (default: the first), by callsign."""
        log = self.vehicle(name or self.mission.vehicles[0].name)
        reports = list(log.adsb)
        out: dict[str, list[TrafficSample]] = {}
        for r, t in zip(reports, log.sim_times_at([r.wall_s for r in reports])):
            x, y, _ = geodetic_to_local(self.mission.origin, r.lat_deg, r.lon_deg)
            out.setdefault(r.callsign, []).append(
                TrafficSample(float(t), r.callsign, x, y, r.course_deg, r.speed_m_s))
        return out

    def mission_on_vehicle(self, name: str) -> list[GeoWaypoint]:
        """The mission stored on vehicle ``name``, downloaded over the GCS link as QGroundControl would."""
        rows = self.telemetry.download_mission(self.mission.vehicle(name).system_id)
        return [GeoWaypoint(lat, lon, alt) for _, lat, lon, alt in rows]

    # -- waiting ------------------------------------------------------------------------------
    def wait_until(self, predicate: Callable[["Telemetry"], bool], *, timeout_s: float = 30.0,
                   what: str = "condition") -> None:
        """Block until ``predicate(telemetry)`` holds (checked as data arrives); AssertionError on timeout."""
        try:
            self.telemetry.wait_until(lambda _: predicate(self), timeout_s=timeout_s, what=what)
        except TimeoutError as exc:
            raise AssertionError(str(exc)) from None

    def wait_for_mode(self, name: str, mode: str, timeout_s: float = 30.0) -> None:
        """Until vehicle ``name`` is in ``mode`` (and a stamped sample after the change has come)."""
        sysid = self.mission.vehicle(name).system_id

        def there(_) -> bool:
            log = self.recorder.vehicles.get(sysid)
            return bool(log and log.last_mode == mode and log.stamps
                        and log.stamps[-1][0] >= log.mode_changes[-1][0])
        self.wait_until(there, timeout_s=timeout_s,
                        what=f"vehicle {name!r} in {mode} (modes so far: {self._modes_or_none(name)})")

    def wait_for_clock(self, t_s: float, *names: str, timeout_s: float = 60.0) -> None:
        """Until every vehicle in ``names`` (default: all) has reported sim time ``t_s``."""
        ids = [self.mission.vehicle(n).system_id for n in names or [v.name for v in self.mission.vehicles]]

        def reached(_) -> bool:
            logs = [self.recorder.vehicles.get(i) for i in ids]
            return all(log is not None and (log.clock_s or 0.0) >= t_s for log in logs)
        self.wait_until(reached, timeout_s=timeout_s, what=f"sim time {t_s:g} s")

    def _modes_or_none(self, name: str) -> str:
        sysid = self.mission.vehicle(name).system_id
        return " -> ".join(self.recorder.log(sysid).modes) if self.recorder.heard(sysid) else "none heard"

    # -- metrics ------------------------------------------------------------------------------
    def report(self, since_mode: str | None = "OFFBOARD") -> RunSummary:
        """SPEC §2 success and metrics (LOS metrics included) from the recorded tracks.

        Tracks run from each vehicle's entry into ``since_mode`` (departure; ``None``: all that
        was recorded) until the last vehicle arrived, as ``companion simulate`` scores a flight.
        """
        tracks = {v.name: self.track(v.name, since_mode) for v in self.mission.vehicles}
        ends = [arrival(tr, self.mission.vehicle(n).goal_enu_m, self.mission.safety.arrival_radius_m)[0]
                for n, tr in tracks.items()]
        if all(t is not None for t in ends):
            t_end = max(ends)  # landing after arrival is not part of the mission's metrics
            tracks = {n: _cut(tr, t_end) for n, tr in tracks.items()}
        return summarize(self.mission, tracks)

    @cached_property
    def _truth(self) -> TruthGeometry:
        return TruthGeometry(self.mission.world)

    # -- assertions ---------------------------------------------------------------------------
    def assert_success(self) -> None:
        """SPEC §2: every vehicle arrived, no obstacle contact, separation and geofence kept."""
        self.assert_clearance()
        self.assert_separation()
        self.assert_geofence()
        self.assert_arrived()

    def assert_arrived(self, *names: str) -> None:
        """Each vehicle (default: all) came within the arrival radius of its goal station, within
        the time limit counted from its departure (entry into OFFBOARD)."""
        radius = self.mission.safety.arrival_radius_m
        for name in names or [v.name for v in self.mission.vehicles]:
            spec, tr = self.mission.vehicle(name), self.track(name)
            t_arrive, _, _ = arrival(tr, spec.goal_enu_m, radius)
            if t_arrive is None:
                d = np.hypot(tr.x_m - spec.goal_enu_m[0], tr.y_m - spec.goal_enu_m[1])
                k = int(np.argmin(d))
                raise AssertionError(
                    f"vehicle {name!r} never reached station {spec.goal} (within {radius:g} m): closest "
                    f"{d[k]:.1f} m at t={tr.t_s[k]:.1f} s; last position ({tr.x_m[-1]:.0f}, {tr.y_m[-1]:.0f}) m "
                    f"at t={tr.t_s[-1]:.1f} s; modes {' -> '.join(self.modes(name))}")
            departures = self.mode_times(name, "OFFBOARD")
            if departures and t_arrive - departures[0] > self.mission.safety.time_limit_s:
                raise AssertionError(f"vehicle {name!r} arrived {t_arrive - departures[0]:.1f} s after departure, "
                                     f"beyond the time limit {self.mission.safety.time_limit_s:g} s")

    def assert_separation(self, min_m: float | None = None) -> None:
        """No two vehicles ever closer than ``min_m`` (default: the mission's), between samples too."""
        min_m = self.mission.safety.min_separation_m if min_m is None else min_m
        names = [v.name for v in self.mission.vehicles]
        tracks = {n: self.track(n) for n in names}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                ta, tb = tracks[a], tracks[b]
                lo, hi = max(ta.t_s[0], tb.t_s[0]), min(ta.t_s[-1], tb.t_s[-1])
                t = np.unique(np.concatenate([ta.t_s, tb.t_s]))
                t = t[(t >= lo) & (t <= hi)]
                if len(t) < 2:
                    continue
                (ax, ay), (bx, by) = ta.at(t), tb.at(t)
                d = pair_min_distance(ax[:-1], ay[:-1], ax[1:], ay[1:], bx[:-1], by[:-1], bx[1:], by[1:])
                k = int(np.argmin(d))
                if d[k] < min_m:
                    raise AssertionError(
                        f"vehicles {a!r} and {b!r} came within {d[k]:.1f} m of each other (minimum {min_m:g} m) "
                        f"between t={t[k]:.1f} and {t[k + 1]:.1f} s, {a} near ({ax[k]:.0f}, {ay[k]:.0f}) m, "
                        f"{b} near ({bx[k]:.0f}, {by[k]:.0f}) m")

    def assert_clearance(self, min_m: float = 0.0) -> None:
        """No vehicle ever touched a TRUE (un-inflated) obstacle footprint, static or moving, checked
        along each step's segment; with ``min_m`` > 0, it also kept that distance."""
        for v in self.mission.vehicles:
            tr = self.track(v.name)
            if len(tr) < 2:
                continue
            x0, y0, x1, y1, t0, t1 = tr.x_m[:-1], tr.y_m[:-1], tr.x_m[1:], tr.y_m[1:], tr.t_s[:-1], tr.t_s[1:]
            d = self._truth.segment_clearance_m(x0, y0, x1, y1, t0, t1)
            k = int(np.argmin(d))
            if d[k] <= 0.0 or d[k] < min_m:
                obstacle = self._nearest_obstacle(x0[k], y0[k], x1[k], y1[k], t0[k], t1[k])
                what = "entered" if d[k] <= 0.0 else f"came within {d[k]:.1f} m (minimum {min_m:g} m) of"
                raise AssertionError(
                    f"vehicle {v.name!r} {what} obstacle {obstacle!r} (true footprint) between t={t0[k]:.1f} and "
                    f"{t1[k]:.1f} s, from ({x0[k]:.0f}, {y0[k]:.0f}) to ({x1[k]:.0f}, {y1[k]:.0f}) m")

    def _nearest_obstacle(self, x0, y0, x1, y1, t0, t1) -> str:
        best, best_id = math.inf, "?"
        for o in self.mission.world.obstacles:
            (dx0, dy0), (dx1, dy1) = o.offset_at(t0), o.offset_at(t1)
            seg = shapely.LineString([(x0 - dx0, y0 - dy0), (x1 - dx1, y1 - dy1)])  # in the obstacle's frame
            d = seg.distance(o.footprint)
            if d < best:
                best, best_id = d, o.id
        return best_id

    def assert_geofence(self) -> None:
        """No vehicle ever left the geofence (the area plus the mission's margin)."""
        w = self.mission.world
        m = w.geofence_margin_m
        for v in self.mission.vehicles:
            tr = self.track(v.name)
            out = np.flatnonzero(~inside_fence(w, tr.x_m, tr.y_m))
            if out.size:
                k = int(out[0])
                raise AssertionError(
                    f"vehicle {v.name!r} left the geofence at t={tr.t_s[k]:.1f} s, at ({tr.x_m[k]:.0f}, "
                    f"{tr.y_m[k]:.0f}) m; fence x {w.x_min_m - m:g}..{w.x_max_m + m:g}, y {w.y_min_m - m:g}.."
                    f"{w.y_max_m + m:g} m")

    def assert_modes_in_order(self, name: str, *modes: str) -> None:
        """Vehicle ``name`` went through ``modes`` in this order (others may come in between)."""
        seen = self.modes(name)
        it = iter(seen)
        if not all(any(m == s for s in it) for m in modes):
            raise AssertionError(f"vehicle {name!r}: expected modes {' -> '.join(modes)} in this order, "
                                 f"reported {' -> '.join(seen)}")

    def assert_mission_matches_plan(self, *names: str, variant: str | None = None) -> None:
        """The mission stored on each vehicle (default: all) is the planned route, waypoint by waypoint
        (what ``companion plan`` / ``upload`` compute for the mission and ``variant``)."""
        from companion.app.flight_plan import ALT_TOLERANCE_M, LATLON_TOLERANCE_DEG, prepare

        plan = self._plans.get(variant)
        if plan is None:
            plan = self._plans[variant] = prepare(self.mission, variant)
        for name in names or [v.name for v in self.mission.vehicles]:
            expected = plan.waypoints(self.mission.vehicle(name))
            stored = self.mission_on_vehicle(name)
            if len(stored) != len(expected):
                raise AssertionError(f"vehicle {name!r} holds {len(stored)} mission items, the plan has "
                                     f"{len(expected)}")
            for i, (got, want) in enumerate(zip(stored, expected)):
                if (abs(got.lat_deg - want.lat_deg) > LATLON_TOLERANCE_DEG
                        or abs(got.lon_deg - want.lon_deg) > LATLON_TOLERANCE_DEG
                        or abs(got.alt_rel_m - want.alt_rel_m) > ALT_TOLERANCE_M):
                    raise AssertionError(
                        f"vehicle {name!r} mission item {i} is ({got.lat_deg:.7f}, {got.lon_deg:.7f}, "
                        f"{got.alt_rel_m:g} m), the plan says ({want.lat_deg:.7f}, {want.lon_deg:.7f}, "
                        f"{want.alt_rel_m:g} m)")


def _cut(track: Track, t_end: float) -> Track:
    """The track up to the first sample at or after ``t_end``."""
    n = min(int(np.searchsorted(track.t_s, t_end, side="left")) + 1, len(track))
    return Track(track.t_s[:n], track.x_m[:n], track.y_m[:n])


# =========================================================================== the stub =======

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


class _SitlFactory:
    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._procs = _Processes()
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
        try:
            self._procs.close()
        finally:
            for r in self._recorders:
                r.close()


# =========================================================================== the companion ==

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
            _signal_group(self.process.pid, sig)
        else:
            self.process.send_signal(sig)

    def wait(self, timeout_s: float = 180.0) -> CompanionRun:
        """Wait for it to exit; AssertionError (with its output) if it does not in ``timeout_s``."""
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            _signal_group(self.process.pid, signal.SIGKILL)
            self.process.wait(10.0)
            raise AssertionError(f"companion run did not finish in {timeout_s:g} s\n{self._result().tail}") from None
        return self._result()

    def survivors(self, timeout_s: float = 5.0) -> dict[int, str]:
        """Processes this run started that are still alive after waiting up to ``timeout_s``
        (e.g. an embedded stub, MAVSDK servers): pid -> command line. Empty is the goal."""
        deadline = time.monotonic() + timeout_s
        while (left := _Processes.survivors(self._tag)) and time.monotonic() < deadline:
            time.sleep(0.05)
        return left

    def _result(self) -> CompanionRun:
        return CompanionRun(self.process.returncode, self._stdout_path.read_text(errors="replace"),
                            self._stderr_path.read_text(errors="replace"), self.out_dir, self.telemetry)


class _CompanionFactory:
    def __init__(self, tmp_path: Path):
        self._tmp = tmp_path
        self._procs = _Processes()
        self._count = 0
        self._recorders: list[BackgroundRecorder] = []

    def start(self, target: Sitl | str | os.PathLike, *args: str, mission: str | os.PathLike | None = None,
              speedup: float = 20.0) -> RunningCompanion:
        """Start ``companion run`` and return at once.

        ``target``: a :class:`Sitl` to connect to, or a mission path to fly on the companion's
        embedded stub (at ``speedup``, on free ports, its GCS link recorded). ``mission``: fly
        this file instead of the stub's (e.g. a bad one). ``args`` go to ``companion run``.
        """
        n, self._count = self._count, self._count + 1
        out_dir = self._tmp / f"companion{n}"
        if isinstance(target, Sitl):
            telemetry: Telemetry = target
            # One stub, one clock for every vehicle and the obstacles: score on it.
            link = [*target.connect_args(), "--shared-clock"]
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

    def __call__(self, target: Sitl | str | os.PathLike, *args: str, timeout_s: float = 180.0,
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
        try:
            self._procs.close()
        finally:
            for r in self._recorders:
                r.close()


# =========================================================================== fixtures =======

def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: end-to-end flights over real UDP (seconds to a minute each)")


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
    """Run the companion: ``run = companion(stub)``, ``companion("missions/x.yaml")``, ``companion.start(stub)``."""
    factory = _CompanionFactory(tmp_path)
    try:
        yield factory
    finally:
        factory.close()
