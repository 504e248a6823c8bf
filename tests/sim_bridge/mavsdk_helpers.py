"""Helpers shared by the MAVSDK tests: one client per link, first-matching subscription item."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from typing import TypeVar

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from sim_bridge.bridge import SimBridge

T = TypeVar("T")


@contextlib.asynccontextmanager
async def mavsdk_client(url: str) -> AsyncIterator[System]:
    """One Mavsdk instance on one link, as the companion runs it; yields the autopilot."""
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(url)
        system = await sdk.first_autopilot(timeout_s=10.0)
        assert system is not None, f"no autopilot on {url}"
        yield system


async def first(agen: AsyncIterator[T], pred: Callable[[T], bool] = lambda _: True, timeout_s: float = 15.0) -> T:
    """The first item of a MAVSDK subscription that satisfies ``pred``; closes the subscription."""
    async with contextlib.aclosing(agen):  # type: ignore[type-var]
        async with asyncio.timeout(timeout_s):
            async for item in agen:
                if pred(item):
                    return item
    raise AssertionError("subscription ended")


def quantize(deg: float) -> float:
    """Degrees as MAVLink's int32 degE7 carries them (and as MAVSDK converts them back)."""
    return round(deg * 1e7) * 1e-7


async def wait_until(sim: SimBridge, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    assert await sim.wait_for(pred, timeout_s), f"timed out waiting for {what}"


async def arm_and_take_off(system: System, sim: SimBridge, index: int) -> None:
    tel, act = TelemetryAsync(system), ActionAsync(system)
    await first(tel.subscribe_health_all_ok(), bool)
    await act.arm()
    await act.takeoff()
    await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD and sim.vehicle(index).in_air, 30.0)
