"""Value types and constants shared by the vehicle's parts (no behaviour here)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any, Hashable, NamedTuple

from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.vehicle.health import HEALTH_SETTLED_S

AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
FORCE_ARM_MAGIC = 21196  # COMPONENT_ARM_DISARM param2 that overrides the checks (MAVLink spec)

KP_POSITION_1_S = 1.0  # position-hold / goto gain: 1 m error -> 1 m/s
KP_ALTITUDE_1_S = 1.0
IN_AIR_ALT_M = 0.3  # land detector: above this the vehicle flies
TOUCHDOWN_ALT_M = 0.02
MISSION_ALT_ACCEPT_M = 1.0  # PX4 NAV_MC_ALT_RAD is 0.8 m
LAND_POSITION_ACCEPT_M = 1.0

# Timings measured on PX4 SITL with SIH (../shared/px4-sih/README.md), in sim seconds.
BOOT_PREFLIGHT_FAIL_S = 2.56  # "Preflight Fail: heading estimate not stable"
BOOT_HEALTHY_S = HEALTH_SETTLED_S  # arming TEMPORARILY_REJECTED before this (sim_bridge.vehicle.health: the boot timeline)
PRFLT_DISARM_LAG_S = 1.0  # "Disarmed by auto preflight disarming" comes COM_DISARM_PRFLT + 1 s after arming
TAKEOFF_DETECT_S = 1.6  # "Takeoff detected" after the take-off command, still on the ground
TAKEOFF_SPOOLUP_S = 3.9  # on the ground this long after the take-off command before it lifts
# The climb, fitted on px4_sih_1x and _4x (z traces: 19 m above ground 17.1 and 18.0 s after the command):
TAKEOFF_RAMP = (0.3, 2.0)  # climb rate from this fraction of MPC_TKO_SPEED at lift-off, linear to all of it in s
TAKEOFF_FAST_FRACTION = 0.55  # MPC_TKO_SPEED up to this fraction of the take-off altitude (PX4: 11 m of 20)
TAKEOFF_APPROACH_KP_1_S = 0.37  # then climb rate per metre below the take-off altitude (PX4: 2.7 m/s peak)
# On the ground this long before "Landing detected" and landed_state ON_GROUND: PX4 SIH's land
# detector took 2.0 s (1x trace), 3.5 s (4x trace) and 3.1 s (live at 4x) from touchdown.
LAND_DETECT_S = 2.9


class LandedState(IntEnum):
    UNDEFINED = mavlink.MAV_LANDED_STATE_UNDEFINED
    ON_GROUND = mavlink.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink.MAV_LANDED_STATE_LANDING


class MissionPhase(Enum):
    """Where the navigator is within the current mission item."""

    TAKEOFF = "takeoff"
    GOTO = "goto"
    HOLD = "hold"
    LAND = "land"


class RtlPhase(Enum):
    CLIMB = "climb"
    RETURN = "return"
    LAND = "land"


class Emit(NamedTuple):
    """A message leaving the vehicle. ``link`` None: every link; ``peer`` None: every peer."""

    msg: Any
    link: str | None = None
    peer: Hashable | None = None


@dataclass(frozen=True, slots=True)
class Setpoint:
    """The last valid offboard setpoint (NED; body frames rotate by yaw only)."""

    body: bool
    use_position: bool
    x_m: float
    y_m: float
    z_m: float
    vx_m_s: float
    vy_m_s: float
    vz_m_s: float
    yaw_rad: float | None
    yaw_rate_rad_s: float | None
    received_t_s: float


@dataclass(frozen=True, slots=True)
class OffboardLoss:
    """Offboard setpoints stopped at ``last_setpoint_t_s``; the failsafe hit at ``failsafe_t_s``."""

    last_setpoint_t_s: float
    failsafe_t_s: float


class Command(NamedTuple):
    """A COMMAND_LONG or COMMAND_INT, normalised."""

    command: int
    params: tuple[float, float, float, float, float, float, float]  # 5, 6 in degrees for global frames
    frame: int | None  # None: COMMAND_LONG
    src: tuple[int, int]


Result = tuple[int, list[Emit]]  # a command handler's MAV_RESULT and the messages it emits


def float_bits_to_int32(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def int32_to_float_bits(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v
