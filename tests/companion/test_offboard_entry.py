"""The pilot's way into OFFBOARD, on the in-process fleet (the stub's PX4-like state machine).

PX4 acks DO_SET_MODE and may then stay in its mode (the setpoint stream not yet live in its
health checks), telling only by its heartbeat: the pilot streams first, asks, and asks again.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

from companion.app.context import FlightContext, RunSettings
from companion.app.flight_log import FlightLog
from companion.app.flight_plan import prepare
from companion.app.pilot import Pilot
from companion.errors import CommandRefused
from companion.sitl.inprocess import InProcessVehicle, open_inprocess_fleet
from companion.vehicle.port import FlightMode, LandedState, VelocityYawRateSetpoint
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
WALL_S = 10.0


class IgnoredRequests:
    """An in-process vehicle whose first ``ignored`` OFFBOARD requests are lost (the setpoint
    still goes out), as PX4 leaves a request it acked without switching."""

    def __init__(self, inner: InProcessVehicle, ignored: int):
        self._inner, self.ignored, self.requests = inner, ignored, 0

    def __getattr__(self, name):
        return getattr(self._inner, name)

    async def start_offboard(self, first: VelocityYawRateSetpoint) -> None:
        self.requests += 1
        if self.requests <= self.ignored:
            await self._inner.send_setpoint(first)
            return
        await self._inner.start_offboard(first)


def _enter(ignored: int) -> tuple[FlightMode, int, list[str], BaseException | None]:
    mission = load_mission(ROOT / "missions" / "small_reference.yaml")
    plan = prepare(mission, "astar-bdwa")

    async def go():
        async with asyncio.timeout(60.0):
            async with open_inprocess_fleet(mission) as fleet:
                inner = fleet.vehicle("a")
                await inner.wait_ready(WALL_S)
                await inner.arm()
                await inner.takeoff(12.0)
                await inner.wait_until(lambda s, p: s.mode is FlightMode.HOLD and s.landed is LandedState.IN_AIR,
                                       WALL_S, "take-off complete")
                a = IgnoredRequests(inner, ignored)
                reports: list[str] = []
                ctx = FlightContext(plan, RunSettings(offboard_entry_s=6.0), FlightLog(None), {"a": a, "b": fleet.vehicle("b")},
                                    report=reports.append)
                pilot = Pilot(ctx, mission.vehicle("a"))
                error = None
                try:
                    await pilot._enter_offboard()
                except CommandRefused as exc:
                    error = exc
                return inner.status().mode, a.requests, reports, error
    return asyncio.run(go())


def test_an_offboard_request_the_autopilot_left_unanswered_is_asked_again():
    mode, requests, reports, error = _enter(ignored=2)
    assert error is None and mode is FlightMode.OFFBOARD
    assert requests == 3 and "a: OFFBOARD after 3 requests" in reports


def test_an_autopilot_that_never_switches_ends_in_one_line_naming_its_mode():
    mode, requests, _, error = _enter(ignored=1000)
    assert mode is FlightMode.HOLD and requests > 3
    assert isinstance(error, CommandRefused) and error.result == "MODE_UNCHANGED"
    assert "still HOLD after" in str(error) and "requests in" in str(error)
