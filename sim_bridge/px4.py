"""PX4 conventions the stub imitates: custom flight modes, and the parameters it owns.

PX4 packs its flight mode into HEARTBEAT.custom_mode as ``main_mode << 16 | sub_mode << 24``
(``px4_custom_mode.h``); a client such as MAVSDK decodes the main mode (and the AUTO sub mode)
from there. Pure: constants and small value types only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum


class Px4MainMode(IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class Px4AutoSubMode(IntEnum):
    NONE = 0
    READY = 1
    TAKEOFF = 2
    LOITER = 3  # what MAVSDK and QGroundControl call "Hold"
    MISSION = 4
    RTL = 5
    LAND = 6


def encode_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 custom_mode word for a (main, sub) mode pair."""
    return (int(main) << 16) | (int(sub) << 24)


def decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """(main, sub) from a PX4 custom_mode word."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


class FlightMode(Enum):
    """The flight modes the stub flies, each with its PX4 (main, sub) encoding."""

    POSCTL = (Px4MainMode.POSCTL, Px4AutoSubMode.NONE)
    HOLD = (Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
    TAKEOFF = (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF)
    MISSION = (Px4MainMode.AUTO, Px4AutoSubMode.MISSION)
    RTL = (Px4MainMode.AUTO, Px4AutoSubMode.RTL)
    LAND = (Px4MainMode.AUTO, Px4AutoSubMode.LAND)
    OFFBOARD = (Px4MainMode.OFFBOARD, Px4AutoSubMode.NONE)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return encode_custom_mode(main, sub)

    @classmethod
    def from_px4(cls, main: int, sub: int) -> "FlightMode | None":
        """The mode a (main, sub) pair asks for, or None if the stub does not fly it.

        Sub modes only mean something under AUTO; PX4 ignores them otherwise.
        """
        if main == Px4MainMode.AUTO:
            for mode in cls:
                if mode.value == (Px4MainMode.AUTO, sub):
                    return mode
            return None
        for mode in cls:
            if mode.value[0] == main and mode.value[0] != Px4MainMode.AUTO:
                return mode
        return None


# PX4 firmware version the stub claims in AUTOPILOT_VERSION: 1.15.0 release (FIRMWARE_VERSION_TYPE_OFFICIAL).
PX4_FLIGHT_SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 0xFF


class ParamType(IntEnum):
    """The MAV_PARAM_TYPE values the stub uses."""

    INT32 = 6
    REAL32 = 9


@dataclass(frozen=True, slots=True)
class ParamDef:
    name: str
    default: float
    min_value: float
    max_value: float
    type: ParamType = ParamType.REAL32
    doc: str = ""

    def accepts(self, value: float) -> bool:
        return math.isfinite(value) and self.min_value <= value <= self.max_value


def default_params(system_id: int, speed_m_s: float, max_yaw_rate_rad_s: float,
                   max_accel_m_s2: float, cruise_alt_m: float) -> tuple[ParamDef, ...]:
    """The parameters one stub vehicle owns, with defaults from its mission vehicle.

    Names and meanings follow PX4. Where PX4's default would fight the mission (speed limits,
    takeoff altitude) the mission's value is the default, as if the airframe had been tuned.
    """
    return (
        ParamDef("MIS_TAKEOFF_ALT", 2.5, 0.0, 5000.0, doc="takeoff altitude above home, m (PX4 default 2.5)"),
        ParamDef("COM_OF_LOSS_T", 1.0, 0.0, 60.0,
                 doc="offboard setpoint timeout before failsafe, s; times the speed factor in sim time, as PX4 SITL"),
        ParamDef("COM_OBL_RC_ACT", 0, 0, 7, ParamType.INT32,
                 doc="offboard-loss action: 0-3 Return (no RC: PX4 SIH falls back to RTL), 4 Land, 5 Hold, 6-7 disarm"),
        ParamDef("COM_DISARM_LAND", 2.0, -1.0, 20.0, doc="auto-disarm delay after landing (sim s); <0 off"),
        ParamDef("COM_DISARM_PRFLT", 10.0, -1.0, 60.0,
                 doc="auto-disarm if no takeoff after arming (sim s; PX4 disarms 1 s later); <0 off"),
        ParamDef("MPC_XY_VEL_MAX", speed_m_s, 0.0, 100.0, doc="horizontal speed limit, m/s"),
        ParamDef("MPC_XY_CRUISE", speed_m_s, 0.0, 100.0, doc="mission / RTL cruise speed, m/s"),
        ParamDef("MPC_ACC_HOR", max_accel_m_s2, 0.1, 100.0, doc="horizontal acceleration limit, m/s^2"),
        ParamDef("MPC_YAWRAUTO_MAX", math.degrees(max_yaw_rate_rad_s), 0.0, 3600.0,
                 doc="yaw-rate limit, deg/s (mission turn radius v/r)"),
        ParamDef("MPC_Z_VEL_MAX_UP", 3.0, 0.1, 20.0, doc="climb-rate limit, m/s"),
        ParamDef("MPC_Z_VEL_MAX_DN", 1.5, 0.1, 20.0, doc="descent-rate limit, m/s"),
        ParamDef("MPC_TKO_SPEED", 1.5, 0.1, 20.0, doc="takeoff climb rate, m/s"),
        ParamDef("MPC_LAND_SPEED", 0.7, 0.1, 10.0, doc="final landing descent rate, m/s"),
        ParamDef("MPC_LAND_ALT1", 10.0, 0.0, 200.0, doc="start slowing the descent below, m"),
        ParamDef("MPC_LAND_ALT2", 5.0, 0.0, 200.0, doc="descend at MPC_LAND_SPEED below, m"),
        ParamDef("MPC_LAND_ALT3", 1.0, 0.0, 200.0, doc="descend at MPC_LAND_CRWL below, m"),
        ParamDef("MPC_LAND_CRWL", 0.3, 0.1, 10.0, doc="crawl speed of the last metre, m/s"),
        ParamDef("NAV_ACC_RAD", 10.0, 0.05, 200.0, doc="default mission acceptance radius, m"),
        ParamDef("RTL_RETURN_ALT", cruise_alt_m, 0.0, 5000.0, doc="RTL return altitude above home, m"),
        ParamDef("BAT_LOW_THR", 0.15, 0.0, 1.0, doc="battery low warning threshold, fraction"),
        ParamDef("BAT_CRIT_THR", 0.07, 0.0, 1.0, doc="battery critical threshold, fraction; no arming below"),
        ParamDef("BAT_EMERGEN_THR", 0.05, 0.0, 1.0, doc="battery emergency threshold, fraction"),
        ParamDef("SYS_HITL", 0, 0, 2, ParamType.INT32, doc="hardware in the loop (read by MAVSDK)"),
        ParamDef("MAV_SYS_ID", system_id, system_id, system_id, ParamType.INT32,
                 doc="system id (read-only here: the link is already bound to it)"),
    )
