"""PX4 conventions the stub imitates: custom flight modes, the parameters it owns, and the
MAVLink identities of the systems that talk to a vehicle.

PX4 packs its flight mode into HEARTBEAT.custom_mode as ``main_mode << 16 | sub_mode << 24``
(``px4_custom_mode.h``); a client such as MAVSDK decodes the main mode (and the AUTO sub mode)
from there. This is the one table of PX4's modes in the project. Pure: constants and small value
types only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum, IntEnum


# Who sends to a vehicle: the companion speaks through MAVSDK, which always introduces itself as
# system 245; a ground station (QGroundControl, MAVProxy) as 255. Both use component 190.
COMPANION_SYSTEM_ID = 245
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER


class Px4MainMode(IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE = 8


class Px4AutoSubMode(IntEnum):
    NONE = 0
    READY = 1
    TAKEOFF = 2
    LOITER = 3  # what MAVSDK and QGroundControl call "Hold"
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9


class Px4PosctlSubMode(IntEnum):
    POSCTL = 0
    ORBIT = 1  # what PX4 reports while flying MAV_CMD_DO_ORBIT


def encode_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 custom_mode word for a (main, sub) mode pair."""
    return (int(main) << 16) | (int(sub) << 24)


def decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """(main, sub) from a PX4 custom_mode word."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def mode_name(custom_mode: int) -> str:
    """A PX4 custom_mode word as MAVSDK names it: ``"OFFBOARD"``, ``"HOLD"`` (AUTO.LOITER),
    ``"TAKEOFF"``... (``PX4(main,sub)`` for a pair PX4 does not define)."""
    main, sub = decode_custom_mode(custom_mode)
    try:
        if main == Px4MainMode.AUTO:
            auto = Px4AutoSubMode(sub)
            if auto is not Px4AutoSubMode.NONE:
                return "HOLD" if auto is Px4AutoSubMode.LOITER else auto.name
        else:
            return Px4MainMode(main).name
    except ValueError:
        pass
    return f"PX4({main},{sub})"


class FlightMode(Enum):
    """The flight modes the stub flies, each with its PX4 (main, sub) encoding."""

    POSCTL = (Px4MainMode.POSCTL, Px4AutoSubMode.NONE)
    HOLD = (Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
    TAKEOFF = (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF)
    MISSION = (Px4MainMode.AUTO, Px4AutoSubMode.MISSION)
    RTL = (Px4MainMode.AUTO, Px4AutoSubMode.RTL)
    LAND = (Px4MainMode.AUTO, Px4AutoSubMode.LAND)
    OFFBOARD = (Px4MainMode.OFFBOARD, Px4AutoSubMode.NONE)
    ORBIT = (Px4MainMode.POSCTL, Px4PosctlSubMode.ORBIT)  # entered by DO_ORBIT only, as on PX4

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
            if mode.value[0] == main and mode.value[0] != Px4MainMode.AUTO and mode is not cls.ORBIT:
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


def _f(name: str, default: float, lo: float, hi: float, doc: str) -> ParamDef:
    return ParamDef(name, default, lo, hi, ParamType.REAL32, doc)


def _i(name: str, default: int, lo: int, hi: int, doc: str) -> ParamDef:
    return ParamDef(name, default, lo, hi, ParamType.INT32, doc)


# The parameters the stub owns, with PX4's names, types and defaults as read from PX4 SITL
# (SIH, main 02e73e3) at boot: ../shared/px4-sih/characterisation/px4_sih_1x.log. Ranges are
# wider than PX4's metadata where a mission needs it (PX4 does not enforce them on PARAM_SET).
# Times are PX4's (sim seconds at 1x; the failsafe code scales loss timeouts by the speed factor).
PX4_PARAMS: tuple[ParamDef, ...] = (
    # take-off, landing, arming
    _f("MIS_TAKEOFF_ALT", 2.5, 0.0, 5000.0, "takeoff altitude above home, m (MAVSDK set_takeoff_altitude)"),
    _f("MPC_TKO_SPEED", 1.5, 0.1, 20.0, "takeoff climb rate, m/s"),
    _f("COM_SPOOLUP_TIME", 1.0, 0.0, 30.0, "motor spool-up time after arming before take-off, s"),
    _f("MPC_LAND_SPEED", 0.7, 0.1, 10.0, "final landing descent rate, m/s"),
    _f("MPC_LAND_ALT1", 10.0, 0.0, 200.0, "start slowing the descent below, m"),
    _f("MPC_LAND_ALT2", 5.0, 0.0, 200.0, "descend at MPC_LAND_SPEED below, m"),
    _f("MPC_LAND_ALT3", 1.0, 0.0, 200.0, "descend at MPC_LAND_CRWL below, m"),
    _f("MPC_LAND_CRWL", 0.3, 0.1, 10.0, "crawl speed of the last metre, m/s"),
    _f("COM_DISARM_LAND", 2.0, -1.0, 20.0, "auto-disarm delay after landing, s; <0 off"),
    _f("COM_DISARM_PRFLT", 10.0, -1.0, 60.0,
       "auto-disarm if no takeoff after arming (sim s; PX4 disarms 1 s later); <0 off"),
    # failsafes
    _f("COM_OF_LOSS_T", 1.0, 0.0, 60.0,
       "offboard setpoint timeout before the failsafe, s; times the speed factor in sim time, as PX4 SITL"),
    _i("COM_OBL_RC_ACT", 0, 0, 7,
       "offboard-loss action: 0-3 Return (no RC: PX4 SIH falls back to RTL), 4 Land, 5 Hold, 6-7 disarm"),
    _i("COM_RCL_EXCEPT", 0, 0, 31, "modes exempt from the RC-loss failsafe, bitmask"),
    _i("NAV_RCL_ACT", 2, 0, 6, "RC-loss action: 0 off, 1 hold, 2 RTL, 3 land, 5 terminate, 6 lockdown"),
    _i("NAV_DLL_ACT", 0, 0, 6, "GCS data-link-loss action: 0 off, 1 hold, 2 RTL, 3 land, 5 terminate, 6 lockdown"),
    _i("COM_DL_LOSS_T", 10, 5, 300, "GCS data-link loss timeout, s"),
    _i("COM_RC_IN_MODE", 1, 0, 4, "manual control source (1: MAVLink joystick only, as PX4 SITL)"),
    _f("COM_FAIL_ACT_T", 5.0, 0.0, 25.0, "delay between a failsafe and its action (hold meanwhile), s"),
    _i("GF_ACTION", 2, 0, 5, "geofence breach action: 0 none, 1 warning, 2 hold, 3 RTL, 4 terminate, 5 land"),
    _i("GF_PREDICT", 0, 0, 1, "geofence: also trigger on the braking point (PX4's experimental predictive breach)"),
    _f("GF_MAX_HOR_DIST", 0.0, 0.0, 10000.0, "maximum horizontal distance from home, m; 0 off"),
    _f("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0, "maximum height above home, m; 0 off"),
    _f("RTL_RETURN_ALT", 60.0, 0.0, 5000.0, "RTL return altitude above home, m"),
    _f("RTL_DESCEND_ALT", 30.0, 0.0, 5000.0, "RTL loiter altitude above home before landing, m"),
    # multicopter limits
    _f("MPC_XY_VEL_MAX", 12.0, 0.0, 100.0, "horizontal speed limit, m/s"),
    _f("MPC_XY_CRUISE", 5.0, 0.0, 100.0, "mission / RTL cruise speed, m/s"),
    _f("MPC_ACC_HOR", 3.0, 0.1, 100.0, "horizontal acceleration in position / offboard control, m/s^2"),
    _f("MPC_ACC_HOR_MAX", 5.0, 0.1, 100.0, "maximum horizontal acceleration, m/s^2"),
    _f("MPC_JERK_AUTO", 4.0, 1.0, 80.0, "jerk limit in auto modes, m/s^3 (GF_PREDICT's stopping distance)"),
    _f("MC_YAWRATE_MAX", 200.0, 0.0, 1800.0, "yaw-rate limit for offboard / manual, deg/s"),
    _f("MPC_YAWRAUTO_MAX", 60.0, 0.0, 3600.0, "yaw-rate limit in auto modes, deg/s"),
    _f("MPC_Z_VEL_MAX_UP", 3.0, 0.1, 20.0, "climb-rate limit, m/s"),
    _f("MPC_Z_VEL_MAX_DN", 1.5, 0.1, 20.0, "descent-rate limit, m/s"),
    _f("NAV_ACC_RAD", 2.0, 0.05, 200.0, "default mission acceptance radius, m"),
    # the multicopter plant's (uav_model.plant.MulticopterLimits reads them by these names)
    _f("MPC_TILTMAX_AIR", 45.0, 1.0, 89.0, "maximum tilt in flight, deg"),
    _f("MPC_XY_VEL_P_ACC", 1.8, 0.0, 20.0, "horizontal velocity P gain, 1/s"),
    _f("MPC_XY_VEL_I_ACC", 0.4, 0.0, 20.0, "horizontal velocity I gain, 1/s^2"),
    _f("MPC_XY_VEL_D_ACC", 0.2, 0.0, 10.0, "horizontal velocity D gain"),
    _f("MPC_Z_VEL_P_ACC", 4.0, 0.0, 20.0, "vertical velocity P gain, 1/s"),
    _f("MPC_ACC_UP_MAX", 4.0, 0.1, 50.0, "maximum upward acceleration, m/s^2"),
    _f("MPC_ACC_DOWN_MAX", 3.0, 0.1, 50.0, "maximum downward acceleration, m/s^2"),
    _f("SIH_KDV", 1.0, 0.0, 100.0, "SIH translational drag, N/(m/s)"),
    _f("SIH_MASS", 1.0, 0.01, 100.0, "SIH vehicle mass, kg"),
    _f("MC_ORBIT_RAD_MAX", 1000.0, 1.0, 10000.0, "largest DO_ORBIT radius, m"),
    # battery
    _f("BAT_LOW_THR", 0.15, 0.0, 1.0, "battery low warning threshold, fraction"),
    _f("BAT_CRIT_THR", 0.07, 0.0, 1.0, "battery critical threshold, fraction; no arming below"),
    _f("BAT_EMERGEN_THR", 0.05, 0.0, 1.0, "battery emergency threshold, fraction"),
    _f("SIM_BAT_DRAIN", 60.0, 1.0, 86400.0, "simulated battery: seconds armed to drain 100 %"),
    _f("SIM_BAT_MIN_PCT", 50.0, 0.0, 100.0, "simulated battery: it never drains below this, %"),
    # system
    _i("SYS_HITL", 0, 0, 2, "hardware in the loop (read by MAVSDK)"),
)

# Defaults a mission vehicle overrides while its plant is the paper's ideal one (the unicycle):
# the speed, turn and acceleration limits come from the mission (the plant reads them), as if the
# airframe had been tuned for it. On the multicopter plant they are PX4's.
UNICYCLE_TUNED = ("MPC_XY_VEL_MAX", "MPC_XY_CRUISE", "MPC_ACC_HOR", "MPC_YAWRAUTO_MAX")


def default_params(system_id: int, speed_m_s: float, max_yaw_rate_rad_s: float, max_accel_m_s2: float,
                   cruise_alt_m: float, *, mission_tuned: bool = True) -> tuple[ParamDef, ...]:
    """The parameters one stub vehicle owns: PX4's defaults, except

    - UNICYCLE_TUNED from the mission when ``mission_tuned`` (the unicycle plant; pass False for
      the multicopter, which flies PX4's);
    - RTL_RETURN_ALT = the mission's cruise altitude, as an operator sets it for a mission.

    MIS_TAKEOFF_ALT stays PX4's 2.5 m: a client sets the mission altitude (MAVSDK's
    ``set_takeoff_altitude``), as it must on PX4.
    """
    tuned = {"RTL_RETURN_ALT": cruise_alt_m}
    if mission_tuned:
        tuned |= dict(zip(UNICYCLE_TUNED, (speed_m_s, speed_m_s, max_accel_m_s2, math.degrees(max_yaw_rate_rad_s)),
                          strict=True))
    defs = tuple(replace(d, default=tuned[d.name]) if d.name in tuned else d for d in PX4_PARAMS)
    sys_id = _i("MAV_SYS_ID", system_id, system_id, system_id,
                "system id (read-only here: the link is already bound to it)")
    return defs + (sys_id,)
