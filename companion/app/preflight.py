"""Pre-flight checks: is each vehicle where, and what, the mission assumes? Pure: no I/O.

    facts (read from each vehicle before anything arms) + mission -> PreflightReport

Each check yields findings of one severity: INFO (reported), WARN (reported; the companion adapts,
e.g. derates the planner to the autopilot's limits) or REFUSE (nothing is armed; the CLI exits 2
with the finding's one line). The numbers are in the messages. ``companion.app.readiness`` reads
the facts and applies the report; docs/companion.md "Flying a real PX4" lists the same checks.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

from uav_model.mission import Mission, VehicleSpec

# What the checks read from the autopilot (PX4 names). The stub owns a subset.
LIMIT_PARAMS = ("MPC_XY_VEL_MAX", "MPC_ACC_HOR", "MC_YAWRATE_MAX", "COM_OF_LOSS_T", "COM_OBL_RC_ACT")
GPS_FIX_3D = 3

# COM_OBL_RC_ACT: what PX4 does when offboard setpoints stop (without RC, 0-2 fall back to Return).
OBL_ACTIONS = {0: "Position mode (without RC: Return)", 1: "Altitude mode (without RC: Return)",
               2: "Manual (without RC: Return)", 3: "Return", 4: "Land", 5: "Hold", 6: "Terminate", 7: "Disarm"}
OBL_HOLD = 5
OBL_RECOVERABLE = frozenset({0, 1, 2, 3, 5})  # the companion resumes OFFBOARD from RTL or Hold
OBL_FATAL = frozenset({6, 7})


class Severity(enum.IntEnum):
    INFO = 0
    WARN = 1
    REFUSE = 2


class Check(enum.Enum):
    LINK = "link"
    STATE = "state"
    STATION = "station"
    HEADING = "heading"
    HOME = "home"
    GPS = "gps"
    SPEED = "speed"
    TURN = "turn"
    OFFBOARD_LOSS = "offboard loss"
    BATTERY = "battery"


@dataclass(frozen=True)
class VehicleFacts:
    """What one vehicle reported before arming (None: not reported)."""

    name: str
    x_east_m: float | None
    y_north_m: float | None
    heading_enu_rad: float | None
    armed: bool
    in_air: bool
    home_ok: bool
    gps_fix_type: int | None
    battery_pct: float | None
    params: Mapping[str, float | None]
    link_anomaly: str | None = None


@dataclass(frozen=True)
class PreflightSettings:
    station_tolerance_m: float | None = None  # None: twice the arrival radius (a landing there may be one radius off)
    plan_from_current: bool = False  # plan from where each vehicle is (and its heading) instead
    heading_tolerance_deg: float = 10.0  # beyond it the pilot yaws to the mission heading first
    min_speed_fraction: float = 0.5  # refuse when the autopilot's speed limit is below this share
    battery_pct_per_s: float = 0.05  # assumed drain in flight (the stub's: 0.03 hover + 0.002 per m/s)
    battery_reserve_pct: float = 5.0
    climb_m_s: float = 1.5  # PX4 MPC_TKO_SPEED
    descent_m_s: float = 1.5  # PX4 MPC_Z_VEL_MAX_DN (MPC_LAND_SPEED 0.7 only for the last metres)
    min_loss_timeout_s: float = 0.3  # COM_OF_LOSS_T below this cannot be fed reliably
    material_turn_widening: float = 1.25  # a derate widening the turns beyond this factor warns; below it: info
    set_failsafe_hold: bool = True  # COM_OBL_RC_ACT becomes 5 (Hold) at connect (RunSettings.failsafe_hold)


@dataclass(frozen=True)
class Finding:
    vehicle: str
    check: Check
    severity: Severity
    message: str

    def line(self) -> str:
        return f"vehicle {self.vehicle!r}: {self.check.value}: {self.message}"


@dataclass(frozen=True)
class PreflightReport:
    findings: tuple[Finding, ...]
    mission: Mission  # the mission to fly: derated, or re-stationed with plan_from_current
    replan: bool  # starts moved: the routes must be planned again

    @property
    def refusals(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity is Severity.REFUSE)


def _param(facts: VehicleFacts, name: str) -> float | None:
    v = facts.params.get(name)
    return v if v is not None and math.isfinite(v) else None


def check_station(spec: VehicleSpec, facts: VehicleFacts, tolerance_m: float,
                  plan_from_current: bool) -> tuple[list[Finding], VehicleSpec]:
    if facts.x_east_m is None or facts.y_north_m is None:
        return [Finding(spec.name, Check.STATION, Severity.REFUSE, "no position reported")], spec
    sx, sy = spec.start_enu_m
    d = math.hypot(facts.x_east_m - sx, facts.y_north_m - sy)
    where = f"({facts.x_east_m:.0f}, {facts.y_north_m:.0f}) m"
    if plan_from_current:
        heading = spec.initial_heading_deg if facts.heading_enu_rad is None else math.degrees(facts.heading_enu_rad)
        moved = dataclasses.replace(spec, start_enu_m=(facts.x_east_m, facts.y_north_m), initial_heading_deg=heading)
        return [Finding(spec.name, Check.STATION, Severity.INFO,
                        f"planning from {where}, {d:.0f} m from station {spec.start}, "
                        f"heading {heading:.0f} deg")], moved
    if d > tolerance_m:
        return [Finding(spec.name, Check.STATION, Severity.REFUSE,
                        f"at {where}, {d:.0f} m from station {spec.start} ({sx:.0f}, {sy:.0f}) m, tolerance "
                        f"{tolerance_m:g} m; move it there, or fly with --plan-from-current")], spec
    return [Finding(spec.name, Check.STATION, Severity.INFO, f"{d:.1f} m from station {spec.start}")], spec


def check_heading(spec: VehicleSpec, facts: VehicleFacts, tolerance_deg: float) -> list[Finding]:
    if facts.heading_enu_rad is None:
        return [Finding(spec.name, Check.HEADING, Severity.WARN, "no heading reported")]
    got = math.degrees(facts.heading_enu_rad)
    err = (got - spec.initial_heading_deg + 180.0) % 360.0 - 180.0
    what = "yaws to it before departure" if abs(err) > tolerance_deg else "within tolerance"
    return [Finding(spec.name, Check.HEADING, Severity.INFO,
                    f"heading {got:.0f} deg (ENU, from east), mission {spec.initial_heading_deg:.0f} deg: {what}")]


def check_position_source(spec: VehicleSpec, facts: VehicleFacts) -> list[Finding]:
    out = []
    if not facts.home_ok:
        out.append(Finding(spec.name, Check.HOME, Severity.REFUSE, "no home position: RTL and landing have no target"))
    if facts.gps_fix_type is None:
        out.append(Finding(spec.name, Check.GPS, Severity.WARN, "GPS fix not reported"))
    elif facts.gps_fix_type < GPS_FIX_3D:
        out.append(Finding(spec.name, Check.GPS, Severity.REFUSE,
                           f"GPS fix type {facts.gps_fix_type}, need a 3D fix ({GPS_FIX_3D})"))
    return out


def check_limits(spec: VehicleSpec, facts: VehicleFacts, s: PreflightSettings) -> tuple[list[Finding], VehicleSpec]:
    """Speed and turn limits against the mission: derate the planner to what the autopilot flies."""
    out: list[Finding] = []
    v, r = spec.speed_m_s, spec.turn_radius_m
    vmax = _param(facts, "MPC_XY_VEL_MAX")
    if vmax is None:
        out.append(Finding(spec.name, Check.SPEED, Severity.WARN, f"MPC_XY_VEL_MAX not reported; assuming {v:g} m/s"))
    elif vmax < s.min_speed_fraction * v:
        out.append(Finding(spec.name, Check.SPEED, Severity.REFUSE,
                           f"MPC_XY_VEL_MAX {vmax:g} m/s is below {s.min_speed_fraction:g} x the mission's {v:g} m/s"))
    elif vmax < v:
        out.append(Finding(spec.name, Check.SPEED, Severity.WARN,
                           f"MPC_XY_VEL_MAX {vmax:g} m/s < mission {v:g} m/s: planning at {vmax:g} m/s"))
        v = vmax
    acc = _param(facts, "MPC_ACC_HOR")
    turns: list[str] = []
    if acc is not None and v * v / r > acc * (1 + 1e-9):
        r_new = v * v / acc
        turns.append(f"a {r:g} m turn at {v:g} m/s needs {v * v / r:.2f} m/s^2 > MPC_ACC_HOR {acc:g}: "
                     f"planning {r_new:.1f} m turns ({math.degrees(v / r_new):.1f} deg/s)")
        r = r_new
    yaw_max = _param(facts, "MC_YAWRATE_MAX")
    if yaw_max is not None and math.degrees(v / r) > yaw_max:
        r_new = v / math.radians(yaw_max)
        turns.append(f"mission yaw rate {math.degrees(v / r):.1f} deg/s > MC_YAWRATE_MAX {yaw_max:g}: "
                     f"planning {r_new:.1f} m turns")
        r = r_new
    # The companion derates the plan to the autopilot's limits; only a material widening warns.
    material = r > s.material_turn_widening * spec.turn_radius_m
    out += [Finding(spec.name, Check.TURN, Severity.WARN if material else Severity.INFO, t) for t in turns]
    if acc is None and yaw_max is None:
        out.append(Finding(spec.name, Check.TURN, Severity.WARN, "MPC_ACC_HOR and MC_YAWRATE_MAX not reported"))
    if (v, r) != (spec.speed_m_s, spec.turn_radius_m):
        spec = dataclasses.replace(spec, speed_m_s=v, turn_radius_m=r)
    return out, spec


def check_offboard_loss(spec: VehicleSpec, facts: VehicleFacts, resend_sim_s: float,
                        s: PreflightSettings) -> list[Finding]:
    out = []
    loss_t = _param(facts, "COM_OF_LOSS_T")
    if loss_t is None:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.WARN, "COM_OF_LOSS_T not reported"))
    elif loss_t < max(s.min_loss_timeout_s, 2 * resend_sim_s):
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.REFUSE,
                           f"COM_OF_LOSS_T {loss_t:g} s is too short for setpoints resent every {resend_sim_s:g} s"))
    action = _param(facts, "COM_OBL_RC_ACT")
    if action is None:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.INFO,
                           "COM_OBL_RC_ACT not reported: an offboard loss is met by resuming from Hold or RTL"))
        return out
    code = int(action)
    name = OBL_ACTIONS.get(code, f"unknown action {code}")
    if s.set_failsafe_hold and code != OBL_HOLD:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.INFO,
                           f"COM_OBL_RC_ACT {code} ({name}): set to {OBL_HOLD} (Hold) before arming"))
    elif code in OBL_FATAL:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.REFUSE,
                           f"COM_OBL_RC_ACT {code} ({name}): an offboard loss would end the flight; set 5 (Hold)"))
    elif code in OBL_RECOVERABLE:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.INFO,
                           f"COM_OBL_RC_ACT {code} ({name}): after a failsafe the companion keeps streaming and "
                           "resumes OFFBOARD"))
    else:
        out.append(Finding(spec.name, Check.OFFBOARD_LOSS, Severity.WARN,
                           f"COM_OBL_RC_ACT {code} ({name}): an offboard loss ends the flight"))
    return out


def battery_need_pct(spec: VehicleSpec, route_m: float, s: PreflightSettings) -> float:
    """Charge to climb, fly the route at the mission speed, and land, plus the reserve."""
    flight_s = spec.cruise_alt_m / s.climb_m_s + route_m / spec.speed_m_s + spec.cruise_alt_m / s.descent_m_s
    return s.battery_reserve_pct + s.battery_pct_per_s * flight_s


def check_battery(spec: VehicleSpec, facts: VehicleFacts, route_m: float, s: PreflightSettings) -> list[Finding]:
    need = battery_need_pct(spec, route_m, s)
    if facts.battery_pct is None:
        return [Finding(spec.name, Check.BATTERY, Severity.WARN,
                        f"battery not reported; the mission needs ~{need:.0f} %")]
    sev = Severity.REFUSE if facts.battery_pct < need else Severity.INFO
    return [Finding(spec.name, Check.BATTERY, sev,
                    f"{facts.battery_pct:.0f} %, the mission needs ~{need:.0f} % ({route_m:.0f} m at "
                    f"{spec.speed_m_s:g} m/s, {s.battery_pct_per_s:g} %/s, {s.battery_reserve_pct:g} % reserve)")]


def check_state(spec: VehicleSpec, facts: VehicleFacts) -> list[Finding]:
    out = []
    if facts.link_anomaly:
        out.append(Finding(spec.name, Check.LINK, Severity.REFUSE,
                           f"{facts.link_anomaly}: two systems with one id on the link?"))
    if facts.armed or facts.in_air:
        out.append(Finding(spec.name, Check.STATE, Severity.REFUSE,
                           "already " + ("in the air" if facts.in_air else "armed") + "; land and disarm it first"))
    return out


def preflight(mission: Mission, facts: Mapping[str, VehicleFacts], route_m: Mapping[str, float],
              resend_sim_s: float, settings: PreflightSettings = PreflightSettings()) -> PreflightReport:
    """Every check for every vehicle; the mission to fly (derated / re-stationed)."""
    findings: list[Finding] = []
    specs: list[VehicleSpec] = []
    tol = (settings.station_tolerance_m if settings.station_tolerance_m is not None
           else 2.0 * mission.safety.arrival_radius_m)
    replan = False
    for spec in mission.vehicles:
        f = facts[spec.name]
        findings += check_state(spec, f)
        found, flown = check_station(spec, f, tol, settings.plan_from_current)
        findings += found
        replan |= flown.start_enu_m != spec.start_enu_m
        findings += check_heading(flown, f, settings.heading_tolerance_deg)
        findings += check_position_source(spec, f)
        found, flown = check_limits(flown, f, settings)
        findings += found
        findings += check_offboard_loss(spec, f, resend_sim_s, settings)
        findings += check_battery(flown, f, route_m.get(spec.name, 0.0), settings)
        specs.append(flown)
    flown_mission = dataclasses.replace(mission, vehicles=tuple(specs))
    return PreflightReport(tuple(findings), flown_mission, replan)
