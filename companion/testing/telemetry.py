"""What a GCS heard from the mission's vehicles (:class:`Telemetry`), read from a test's thread.

A :class:`BackgroundRecorder` runs the asyncio :class:`~companion.testing.recorder.TelemetryRecorder`
on its own event loop, so a synchronous test can wait on telemetry and read the vehicles' logs.
:class:`Telemetry` names vehicles as the mission does, gives their tracks, modes, traffic and
stored missions, scores a flight (SPEC §2, from :mod:`companion.planning.metrics`) and makes
the assertions of :class:`~companion.testing.assertions.TelemetryAssertions`.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from uav_model.frames import geodetic_to_local
from uav_model.mission import Mission
from companion.planning.metrics import RunSummary, Track, summarize, until_last_arrival
from companion.testing.assertions import TelemetryAssertions
from companion.testing.recorder import TelemetryRecorder, VehicleLog
from companion.vehicle.port import GeoWaypoint


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


@dataclass(frozen=True)
class TrafficSample:
    """An ADS-B report heard from a vehicle, in the mission's ENU frame at the vehicle's sim time."""

    t_s: float
    callsign: str
    x_m: float
    y_m: float
    course_deg: float
    speed_m_s: float


class Telemetry(TelemetryAssertions):
    """What a GCS heard from the mission's vehicles, with the assertions a scenario test makes.

    Vehicles are named as in the mission file. Times are the vehicle's sim time (s since the
    stub started), which is also the clock the mission's moving obstacles follow.
    """

    def __init__(self, mission: Mission, mission_path: Path, recorder: BackgroundRecorder):
        self.mission = mission
        self.mission_path = mission_path
        self.telemetry = recorder

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
        return summarize(self.mission, until_last_arrival(self.mission, tracks))
