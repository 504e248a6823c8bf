"""The latest known state of one vehicle, and waiting for it to change (asyncio, no I/O).

Adapters feed it from their telemetry pumps; the runner reads snapshots and waits for news with
a timeout. One board per vehicle, owned by its adapter: there is no shared mutable state.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import Callable, Mapping

from companion.errors import TelemetryLost
from companion.vehicle.port import PoseSample, TrafficReport, VehicleStatus


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
        self.clock_t_sim_s: float | None = None
        self.clock_t_wall_s: float | None = None
        self.latest_clock_s: float | None = None
        # Sim seconds per wall second, smoothed; None until measured.
        self.sim_rate: float | None = None

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

    async def note_clock(self, t_sim_s: float) -> None:
        """Record the vehicle's clock from a stamped message and update the sim-rate estimate.

        Waiters are woken too: a clock that runs on while positions do not is how a stale
        position is noticed in sim time.
        """
        now = time.monotonic()
        if self.clock_t_sim_s is not None and self.clock_t_wall_s is not None:
            d_wall = now - self.clock_t_wall_s
            d_sim = t_sim_s - self.clock_t_sim_s
            if d_wall > 0.2 and d_sim >= 0:
                rate = d_sim / d_wall
                self.sim_rate = rate if self.sim_rate is None else 0.8 * self.sim_rate + 0.2 * rate
                self.clock_t_sim_s, self.clock_t_wall_s = t_sim_s, now
            elif d_sim < 0:  # the vehicle rebooted: restart the estimate
                self.clock_t_sim_s, self.clock_t_wall_s = t_sim_s, now
        else:
            self.clock_t_sim_s, self.clock_t_wall_s = t_sim_s, now
        self.latest_clock_s = t_sim_s
        await self._notify()

    async def put_pose(self, **fields: float) -> PoseSample:
        self._seq += 1
        self._pose = PoseSample(seq=self._seq, t_wall_s=time.monotonic(), **fields)
        await self._notify()
        return self._pose

    async def put_status(self, **changes) -> None:
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
