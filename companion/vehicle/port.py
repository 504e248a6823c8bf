"""The Vehicle port: what the mission runner needs from one autopilot, in the mission's frame.

Everything that crosses this port is a frozen value with its unit and frame in its name.
Positions and velocities are local ENU metres from the mission origin (x east, y north), headings
are math angles (from +x, counter-clockwise), yaw rates are counter-clockwise positive. An adapter
(``mavsdk_vehicle`` for real links) converts to and from the autopilot's NED world through
:mod:`uav_model.frames` and nowhere else.

Time on this side is the *vehicle's* sim clock (``t_sim_s``, from MAVLink ``time_boot_ms``), so
that the runner works at any speed factor; ``t_wall_s`` (``time.monotonic``) is kept only to bound
how long the runner waits for a link that has gone quiet.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


class FlightMode(enum.Enum):
    """The autopilot's flight mode, as MAVSDK names PX4's modes."""

    UNKNOWN = "UNKNOWN"
    READY = "READY"
    TAKEOFF = "TAKEOFF"
    HOLD = "HOLD"
    MISSION = "MISSION"
    RETURN_TO_LAUNCH = "RTL"
    LAND = "LAND"
    OFFBOARD = "OFFBOARD"
    POSCTL = "POSCTL"
    OTHER = "OTHER"


class LandedState(enum.Enum):
    UNKNOWN = "UNKNOWN"
    ON_GROUND = "ON_GROUND"
    IN_AIR = "IN_AIR"
    TAKING_OFF = "TAKING_OFF"
    LANDING = "LANDING"


@dataclass(frozen=True, slots=True)
class PoseSample:
    """One stamped position/attitude sample of a vehicle, in the mission's ENU frame."""

    t_sim_s: float  # the vehicle's clock (time since boot), seconds
    t_wall_s: float  # time.monotonic() when it arrived
    x_east_m: float
    y_north_m: float
    alt_rel_m: float  # above home, up positive
    vx_east_m_s: float
    vy_north_m_s: float
    heading_enu_rad: float
    seq: int  # strictly increasing per vehicle; lets waiters ask for "something newer"
    plausible: bool = True  # False: it jumped from the last plausible sample (another system's?); kept out of metrics

    @property
    def ground_speed_m_s(self) -> float:
        return (self.vx_east_m_s ** 2 + self.vy_north_m_s ** 2) ** 0.5


@dataclass(frozen=True, slots=True)
class VehicleStatus:
    """Latest discrete state of a vehicle."""

    armed: bool = False
    mode: FlightMode = FlightMode.UNKNOWN
    landed: LandedState = LandedState.UNKNOWN
    health_ok: bool = False
    battery_pct: float | None = None
    home_ok: bool = False  # the autopilot has a home position
    gps_fix_type: int | None = None  # GPS_FIX_TYPE (3 = 3D fix); None until reported
    failsafe_notices: int = 0  # "Failsafe activated" / "Offboard control lost" texts heard so far
    last_failsafe_t_sim_s: float | None = None  # the vehicle's clock when the latest of them was heard
    fence_notices: int = 0  # breach texts heard so far ("Geofence: ...", PX4's notice; board.FENCE_TEXTS)
    last_fence_t_sim_s: float | None = None  # the vehicle's clock when the latest of them was heard
    last_fence_text: str | None = None  # its words (PX4 names the fence: custom zones, distance, altitude)
    link_anomaly: str | None = None  # telemetry no single vehicle can produce (two systems on one link)
    link_conflict: str | None = None  # this vehicle's system id heard from a second source address (LinkGuard)
    mode_changes: int = 0  # how many mode changes were heard: a brief failsafe shows even if it is over
    last_other_mode: FlightMode | None = None  # the latest mode heard that was not OFFBOARD


@dataclass(frozen=True, slots=True)
class TrafficReport:
    """A moving obstacle reported over the link (ADSB_VEHICLE), in the mission's ENU frame.

    ``t_sim_s`` is the reporting vehicle's clock when it sent the report (ADSB_VEHICLE carries
    none: the link guard reads it from the vehicle's stamped frames before it), else the newest
    clock at reception.
    """

    callsign: str
    x_east_m: float
    y_north_m: float
    vx_east_m_s: float
    vy_north_m_s: float
    t_sim_s: float
    t_wall_s: float
    via: str  # name of the vehicle whose link carried it


@dataclass(frozen=True, slots=True)
class VelocityYawRateSetpoint:
    """Body-frame offboard setpoint: forward speed, climb rate and a CCW-positive yaw rate."""

    forward_m_s: float
    yaw_rate_enu_rad_s: float
    climb_m_s: float = 0.0


HOVER = VelocityYawRateSetpoint(0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class GeoWaypoint:
    """A route point as the autopilot stores it (MISSION_ITEM_INT, NAV_WAYPOINT)."""

    lat_deg: float
    lon_deg: float
    alt_rel_m: float


@dataclass(frozen=True, slots=True)
class GeoFenceZone:
    """One geofence zone as the autopilot stores it (mission_type FENCE): a circle or a polygon.

    ``inclusion``: the vehicle must stay inside (else outside). A polygon has ``vertices_deg``
    ((lat, lon) pairs, no closing repeat); a circle has ``center_deg`` and ``radius_m``.
    """

    inclusion: bool
    vertices_deg: tuple[tuple[float, float], ...] = ()
    center_deg: tuple[float, float] | None = None
    radius_m: float = 0.0

    @property
    def is_circle(self) -> bool:
        return self.center_deg is not None


@runtime_checkable
class Vehicle(Protocol):
    """One connected autopilot. Adapters are opened as async context managers and closed by them.

    Every method that talks to the vehicle raises a :mod:`companion.errors` error on refusal or
    timeout; none of them waits forever.
    """

    @property
    def name(self) -> str: ...

    @property
    def system_id(self) -> int: ...

    def latest_pose(self) -> PoseSample | None: ...

    def clock_s(self) -> float | None:
        """The vehicle's clock as last heard (sim seconds), from any stamped message."""
        ...

    def sim_rate(self) -> float | None:
        """Measured sim seconds per wall second, None until known."""
        ...

    def status(self) -> VehicleStatus: ...

    def traffic(self) -> Mapping[str, TrafficReport]:
        """Latest report per callsign that this vehicle's link carried."""
        ...

    async def next_pose(self, after_seq: int, timeout_s: float) -> PoseSample:
        """The first sample newer than ``after_seq``; TelemetryLost after ``timeout_s`` wall."""
        ...

    async def wait_until(self, predicate: Callable[[VehicleStatus, PoseSample | None], bool],
                         timeout_s: float, what: str) -> None:
        """Return once ``predicate(status, pose)`` holds; TelemetryLost after ``timeout_s`` wall."""
        ...

    async def wait_ready(self, timeout_s: float) -> None: ...

    async def get_param(self, name: str) -> float | None:
        """The autopilot's parameter ``name``; None if it has no such parameter."""
        ...

    async def set_param(self, name: str, value: float) -> None:
        """Set a parameter and confirm it (CommandRefused if it stays different)."""
        ...

    async def set_mode(self, mode: FlightMode, what: str = "set mode") -> None:
        """Ask for a flight mode (HOLD to re-arm after a landing in LAND, as PX4 users do)."""
        ...

    async def upload_route(self, waypoints: Sequence[GeoWaypoint], acceptance_radius_m: float) -> None: ...

    async def download_route(self) -> tuple[GeoWaypoint, ...]: ...

    async def upload_fence(self, zones: Sequence[GeoFenceZone]) -> None:
        """Replace the autopilot's geofence (MAVLink mission protocol, mission_type FENCE)."""
        ...

    async def download_fence(self) -> tuple[GeoFenceZone, ...]:
        """The geofence the autopilot stores, read back with the mission protocol."""
        ...

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def takeoff(self, alt_rel_m: float) -> None: ...

    async def start_offboard(self, first: VelocityYawRateSetpoint) -> None: ...

    async def send_setpoint(self, setpoint: VelocityYawRateSetpoint) -> None: ...

    async def hold(self) -> None: ...

    async def land(self) -> None: ...
