"""The latest known state of one vehicle, and waiting for it to change (asyncio, no I/O).

Adapters feed it from their telemetry pumps; the runner reads snapshots and waits for news with
a timeout. One board per vehicle, owned by its adapter: there is no shared mutable state.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections import deque
from collections.abc import Callable, Mapping

from companion.errors import TelemetryLost
from companion.vehicle.sim_rate import SimRateEstimator
from companion.vehicle.port import FlightMode, PoseSample, TrafficReport, VehicleStatus

# STATUSTEXTs that mean the autopilot took control away because setpoints stopped: PX4's
# "Failsafe activated" (then RTL or Hold, per COM_OBL_RC_ACT) and the stub's own wording.
FAILSAFE_TEXTS = ("failsafe activated", "offboard control lost")
# A geofence breach. PX4's STATUSTEXT is "Geofence: approaching or outside geofence" (or
# "Geofence: exceeding maximum distance to Home", "... altitude above Home"; the binary of
# ../shared/px4-sih holds these), its event and older PX4 "Geofence violation: ..." with the same
# ending. The same words inside "Arming denied: ..." are a refusal on the ground, "Geofence
# violation for waypoint N" a mission check at upload: neither is a breach.
FENCE_TEXTS = ("geofence violation:", "geofence: approaching", "geofence: exceeding", "outside geofence")


# Faster than any multicopter this companion flies: a sample this far from the last one is another
# vehicle's (two systems with one id on the link), not a fast flight.
JUMP_SPEED_M_S = 60.0
JUMP_MIN_M = 30.0
CLOCK_BACKSTEPS = 2  # clock steps back by > 1 s: one is a reboot, two are two clocks interleaved
# One jump can be a pairing artefact (MAVSDK's position carries no stamp: after a link gap it is
# paired with the newest attitude); two systems interleaved jump on most samples.
JUMPS_TO_FLAG = 3
JUMP_WINDOW = 20  # samples


def implausible_jump(prev: PoseSample, x_east_m: float, y_north_m: float, t_sim_s: float) -> str | None:
    """Why a new sample cannot follow ``prev`` on one vehicle, or None."""
    d = ((x_east_m - prev.x_east_m) ** 2 + (y_north_m - prev.y_north_m) ** 2) ** 0.5
    dt = max(t_sim_s - prev.t_sim_s, 0.05)
    if d > JUMP_MIN_M and d / dt > JUMP_SPEED_M_S:
        return (f"position jumped {d:.0f} m in {t_sim_s - prev.t_sim_s:.2f} s sim "
                f"({d / dt:.0f} m/s; no vehicle here flies above {JUMP_SPEED_M_S:g})")
    return None


def is_failsafe_text(text: str) -> bool:
    low = text.lower()
    return any(t in low for t in FAILSAFE_TEXTS)


def is_fence_text(text: str) -> bool:
    low = text.lower()
    return "denied" not in low and any(t in low for t in FENCE_TEXTS)


class VehicleBoard:
    """Latest pose, status and traffic of one vehicle, with change notification."""

    def __init__(self, name: str):
        self.name = name
        self._pose: PoseSample | None = None
        self._status = VehicleStatus()
        self._traffic: dict[str, TrafficReport] = {}
        self._changed = asyncio.Condition()
        self._seq = 0
        # The vehicle's clock as last seen in any stamped message (attitude), for staleness.
        self.latest_clock_s: float | None = None
        self.latest_clock_wall_s: float | None = None  # time.monotonic() when latest_clock_s arrived
        self.texts: deque[tuple[float, str]] = deque(maxlen=64)  # (wall, STATUSTEXT) as heard
        self._clock_backsteps = 0
        self._jumps: deque[bool] = deque(maxlen=JUMP_WINDOW)
        self._last_plausible: PoseSample | None = None
        self._rate = SimRateEstimator()  # sim seconds per wall second, robust to late bursts

    @property
    def sim_rate(self) -> float | None:
        """Sim seconds per wall second (:mod:`companion.vehicle.sim_rate`); None until measured."""
        return self._rate.rate

    # -- readers -------------------------------------------------------------------------
    def pose(self) -> PoseSample | None:
        return self._pose

    def status(self) -> VehicleStatus:
        return self._status

    def traffic(self) -> Mapping[str, TrafficReport]:
        return dict(self._traffic)

    async def next_pose(self, after_seq: int, timeout_s: float) -> PoseSample:
        def newer() -> bool:
            return self._pose is not None and self._pose.seq > after_seq
        await self._wait(newer, timeout_s, "a new position sample")
        assert self._pose is not None
        return self._pose

    async def wait_until(self, predicate: Callable[[VehicleStatus, PoseSample | None], bool],
                         timeout_s: float, what: str) -> None:
        await self._wait(lambda: predicate(self._status, self._pose), timeout_s, what)

    async def _wait(self, ready: Callable[[], bool], timeout_s: float, what: str) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                async with self._changed:
                    await self._changed.wait_for(ready)
        except TimeoutError:
            raise TelemetryLost(f"no {what} within {timeout_s:.2f} s (wall)", vehicle=self.name) from None

    # -- writers (adapters) ---------------------------------------------------------------
    async def _notify(self) -> None:
        async with self._changed:
            self._changed.notify_all()

    async def note_clock(self, t_sim_s: float, wall_s: float | None = None) -> None:
        """Record the vehicle's clock from a stamped message (seen at ``wall_s``, default now) and
        update the sim-rate estimate.

        Waiters are woken too: a clock that runs on while positions do not is how a stale
        position is noticed in sim time.
        """
        now = time.monotonic() if wall_s is None else wall_s
        self._rate.add(now, t_sim_s)
        if self.latest_clock_s is not None and t_sim_s < self.latest_clock_s - 1.0:
            self._clock_backsteps += 1
            if self._clock_backsteps >= CLOCK_BACKSTEPS and self._status.link_anomaly is None:
                self._status = dataclasses.replace(self._status, link_anomaly=(
                    f"the vehicle clock stepped back {self._clock_backsteps} times "
                    f"(last {self.latest_clock_s:.1f} -> {t_sim_s:.1f} s)"))
        self.latest_clock_s = t_sim_s
        self.latest_clock_wall_s = now
        await self._notify()

    async def put_text(self, text: str) -> None:
        """A STATUSTEXT; failsafe notices are counted in the status (PX4 splits long texts, and
        appends a tab: the match is on a lower-cased fragment)."""
        text = text.strip()
        self.texts.append((time.monotonic(), text))
        clock = self.latest_clock_s if self.latest_clock_s is not None else float("-inf")
        if is_failsafe_text(text):
            await self.put_status(failsafe_notices=self._status.failsafe_notices + 1, last_failsafe_t_sim_s=clock)
        if is_fence_text(text):
            await self.put_status(fence_notices=self._status.fence_notices + 1, last_fence_t_sim_s=clock,
                                  last_fence_text=text)

    async def put_pose(self, **fields: float) -> PoseSample:
        """A new sample. One that jumped from the last plausible one is marked implausible (the
        flown path leaves it out); enough of them flag a link anomaly."""
        why = None
        if self._last_plausible is not None:
            why = implausible_jump(self._last_plausible, fields["x_east_m"], fields["y_north_m"], fields["t_sim_s"])
            if self._status.link_anomaly is None:
                self._jumps.append(why is not None)
                if why is not None and sum(self._jumps) >= JUMPS_TO_FLAG:
                    self._status = dataclasses.replace(self._status, link_anomaly=(
                        f"{sum(self._jumps)} of the last {len(self._jumps)} positions jumped (last: {why})"))
        self._seq += 1
        self._pose = PoseSample(seq=self._seq, t_wall_s=time.monotonic(), plausible=why is None, **fields)
        if why is None:
            self._last_plausible = self._pose
        await self._notify()
        return self._pose

    async def put_status(self, **changes) -> None:
        mode = changes.get("mode")
        if mode is not None and mode is not self._status.mode:
            changes["mode_changes"] = self._status.mode_changes + 1
            if mode is not FlightMode.OFFBOARD:
                changes["last_other_mode"] = mode
        self._status = dataclasses.replace(self._status, **changes)
        await self._notify()

    async def put_traffic(self, report: TrafficReport) -> None:
        self._traffic[report.callsign] = report
        await self._notify()


class BoardReaders:
    """The Vehicle port's readers, answered from a :class:`VehicleBoard` in ``self._board``:
    every adapter keeps its telemetry on a board, so they all read it the same way."""

    _board: VehicleBoard

    @property
    def board(self) -> VehicleBoard:
        return self._board

    def latest_pose(self) -> PoseSample | None:
        return self._board.pose()

    def clock_s(self) -> float | None:
        return self._board.latest_clock_s

    def sim_rate(self) -> float | None:
        return self._board.sim_rate

    def status(self) -> VehicleStatus:
        return self._board.status()

    def traffic(self) -> Mapping[str, TrafficReport]:
        return self._board.traffic()

    async def next_pose(self, after_seq: int, timeout_s: float) -> PoseSample:
        return await self._board.next_pose(after_seq, timeout_s)

    async def wait_until(self, predicate: Callable[[VehicleStatus, PoseSample | None], bool],
                         timeout_s: float, what: str) -> None:
        await self._board.wait_until(predicate, timeout_s, what)
