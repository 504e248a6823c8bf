"""Typed errors of the companion's runtime (links, vehicles, the mission runner).

Raised, never printed; ``str()`` is one line that names the vehicle and says what to do.

    CompanionError                 anything the flying side of the companion refuses or loses
     ├── LinkError                 the MAVLink link to a vehicle is missing or gone
     │    ├── ConnectTimeout       no autopilot heartbeat on the connection URL in time
     │    └── TelemetryLost        telemetry stopped (or went stale) for longer than allowed
     ├── VehicleNotReady           connected, but health checks did not pass in time
     ├── CommandRefused            the vehicle answered a command with a refusal or timed out
     │                             (arm, takeoff, offboard start, hold, land, param set ...);
     │                             carries ``vehicle``, ``command``, ``result`` and ``retryable``
     ├── MissionUploadError        upload or download failed, or the read-back differs
     ├── PreflightRefused          a pre-flight check failed before anything armed (CLI exit 2)
     │    ├── LinkConflict         two autopilots answer as one system on a link, or the port is taken
     │    ├── SigningRefused       the companion and the autopilot disagree about MAVLink 2 signing
     │    └── GeofenceRefused      the geofence could not be uploaded or read back: the flight
     │                             is refused before anything arms (CLI exit 2)
     └── MissionAborted            a safety monitor or the operator stopped the flight;
                                   carries the SPEC §2 failure ``reason`` (``link_lost``,
                                   ``interrupted``, ``geofence``, ``separation`` ...)

Bad input is not a CompanionError: :class:`uav_model.mission.MissionError` (and the planner's
:class:`companion.planning.errors.NoPath`, which the CLI turns into a MissionError) are raised
before anything connects, and the CLI exits 2 on them.
"""

from __future__ import annotations

import asyncio


class CompanionError(Exception):
    """Base of every runtime error of the companion. ``vehicle`` names the vehicle, if any."""

    def __init__(self, message: str, *, vehicle: str | None = None):
        self.vehicle = vehicle
        self.message = message
        super().__init__(message)

    def __str__(self) -> str:
        return f"vehicle {self.vehicle!r}: {self.message}" if self.vehicle else self.message


class LinkError(CompanionError):
    """The MAVLink link to a vehicle is missing or gone."""


class ConnectTimeout(LinkError):
    """No autopilot appeared on the connection within the timeout."""


class TelemetryLost(LinkError):
    """Telemetry stopped arriving (or stopped advancing in sim time) for too long."""


class VehicleNotReady(CompanionError):
    """The vehicle is connected but its health checks did not pass in time."""


class CommandRefused(CompanionError):
    """The vehicle refused a command or did not answer it.

    ``result`` is the autopilot's / MAVSDK's result name (``COMMAND_DENIED``, ``TIMEOUT`` ...).
    ``retryable`` is True for answers that may change on a second try (busy, timeout).
    """

    def __init__(self, command: str, result: str, *, vehicle: str | None = None,
                 retryable: bool = False, detail: str = ""):
        self.command = command
        self.result = result
        self.retryable = retryable
        self.detail = detail
        extra = f" ({detail})" if detail else ""
        super().__init__(f"{command} refused: {result}{extra}", vehicle=vehicle)


class MissionUploadError(CompanionError):
    """The route could not be uploaded, downloaded, or the read-back differs from it."""


class PreflightRefused(CompanionError):
    """A pre-flight check failed: nothing was armed. The message carries the numbers and the fix."""


class LinkConflict(PreflightRefused):
    """Two autopilots answer as one system id on one link, or the link's port is taken."""


class SigningRefused(PreflightRefused):
    """The companion and the autopilot disagree about MAVLink 2 signing (one signs, the other does
    not, or their keys differ), or the link cannot be signed: nothing armed."""


class GeofenceRefused(PreflightRefused):
    """The autopilot's geofence could not be set (refused, lost, or read back different): nothing armed."""


class MissionAborted(CompanionError):
    """The flight was stopped before success; ``reason`` is the SPEC §2 failure reason."""

    def __init__(self, reason: str, message: str, *, vehicle: str | None = None):
        self.reason = reason
        super().__init__(message, vehicle=vehicle)


def primary_error(group: BaseExceptionGroup) -> BaseException:
    """The error that matters in a task group's failure: the first leaf that is not a
    cancellation (the others were cancelled because of it)."""
    leaves: list[BaseException] = []

    def walk(e: BaseException) -> None:
        if isinstance(e, BaseExceptionGroup):
            for sub in e.exceptions:
                walk(sub)
        else:
            leaves.append(e)
    walk(group)
    for e in leaves:
        if not isinstance(e, asyncio.CancelledError):
            return e
    return leaves[0] if leaves else group
