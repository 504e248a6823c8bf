"""Opening a :class:`companion.vehicle.mavsdk_vehicle.MavsdkVehicle`: the link guard on a
``udpin://`` port, one Mavsdk instance, the first autopilot heard and its system id checked, the
telemetry pumps run while the context is open; leaving it cancels them and destroys the instance
off the event loop, within a bound."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, MavsdkConnectionError

from uav_model import frames
from companion.errors import ConnectTimeout, LinkError
from companion.vehicle.link_guard import LinkGuard, guarded_link
from companion.vehicle.mavsdk_vehicle import STREAM_RATE_HZ, MavsdkVehicle

log = logging.getLogger(__name__)

SHUTDOWN_TIMEOUT_S = 5.0  # wall; destroying an instance joins its threads (then companion.app.event_loop.leave)


@asynccontextmanager
async def open_mavsdk_vehicle(name: str, system_id: int, url: str, origin: frames.GeoOrigin, *,
                              connect_timeout_s: float = 15.0, telemetry_hz: float = STREAM_RATE_HZ,
                              signing_key: bytes | None = None) -> AsyncIterator[MavsdkVehicle]:
    """Connect to the autopilot on ``url`` and run its telemetry pumps while the context is open.
    A ``udpin://`` port is held by a :class:`LinkGuard` that sees each datagram's source (and
    signs the link with ``signing_key``)."""
    async with guarded_link(url, system_id, name, signing_key) as (mavsdk_url, guard):
        async with _open(name, system_id, url, mavsdk_url, guard, origin, connect_timeout_s, telemetry_hz) as vehicle:
            yield vehicle


@asynccontextmanager
async def _open(name: str, system_id: int, url: str, mavsdk_url: str, guard: LinkGuard | None,
                origin: frames.GeoOrigin, connect_timeout_s: float, telemetry_hz: float,
                ) -> AsyncIterator[MavsdkVehicle]:
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        try:
            async with asyncio.timeout(connect_timeout_s):
                await sdk.add_any_connection(mavsdk_url)
        except MavsdkConnectionError as exc:
            raise LinkError(f"cannot open connection {url!r}: {exc}", vehicle=name) from None
        except TimeoutError:
            raise ConnectTimeout(f"opening {url!r} took longer than {connect_timeout_s:g} s", vehicle=name) from None
        # A disagreement about signing is named before MAVSDK waits for a heartbeat in vain.
        heard = guard is None or await guard.first_word(connect_timeout_s, name)
        try:
            async with asyncio.timeout(connect_timeout_s + 1.0):
                system = await sdk.first_autopilot(timeout_s=connect_timeout_s) if heard else None
        except TimeoutError:
            system = None
        if system is None:
            raise ConnectTimeout(f"no autopilot heartbeat on {url} within {connect_timeout_s:g} s", vehicle=name)
        got = await system.get_system_id()
        if got != system_id:
            raise LinkError(f"the autopilot on {url} has system id {got}, the mission expects {system_id}",
                            vehicle=name)
        vehicle = MavsdkVehicle(name, system_id, system, origin, guard, telemetry_hz)
        try:
            async with asyncio.TaskGroup() as tg:
                pumps = vehicle.start_pumps(tg)
                try:
                    yield vehicle
                finally:
                    for task in pumps:
                        task.cancel()
        except BaseExceptionGroup as group:
            # The pumps only end by cancellation, so the group holds the caller's own error:
            # hand it back unwrapped so that ``except CommandRefused`` still works.
            if len(group.exceptions) == 1:
                raise group.exceptions[0] from None
            raise
        finally:
            await vehicle.close_streams()
    finally:
        # Joins MAVSDK's threads: keep it off the event loop, and do not wait forever for it.
        try:
            async with asyncio.timeout(SHUTDOWN_TIMEOUT_S):
                await asyncio.to_thread(sdk.destroy)
        except TimeoutError:
            log.warning("vehicle %s: MAVSDK did not shut down within %g s", name, SHUTDOWN_TIMEOUT_S)
