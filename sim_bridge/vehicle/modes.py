"""Arming, flight-mode switching, offboard setpoints and the failsafes PX4 applies to them."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Hashable

from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.vehicle.mission_protocol import MISSION
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.vehicle.types import (
    BOOT_HEALTHY_S, BOOT_PREFLIGHT_FAIL_S, PRFLT_DISARM_LAG_S, TAKEOFF_SPOOLUP_S, Emit, OffboardLoss, Result,
    RtlPhase, Setpoint,
)

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

# SET_POSITION_TARGET_LOCAL_NED type_mask bits (set = ignore that field).
MASK_POSITION = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
                 | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE)
MASK_VELOCITY = (mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
                 | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
MASK_YAW = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
MASK_YAW_RATE = mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
BODY_FRAMES = frozenset({mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED})
LOCAL_FRAMES = frozenset({mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED})


class Modes:
    """Which mode the vehicle flies and whether it may: arming checks, mode rules, failsafes."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        self.armed_t: float | None = None
        self.took_off_since_arm = False
        self.landed_t: float | None = None
        self.setpoint: Setpoint | None = None
        self.offboard_losses: list[OffboardLoss] = []
        self.failsafe_t: float | None = None  # an offboard-loss failsafe is active since then
        self.takeoff_start_t: float | None = None  # armed and told to take off at
        self.mode_before_land: FlightMode | None = None
        self._boot_text_sent = False

    # ---------------------------------------------------------------- arming -------------
    def healthy(self) -> bool:
        """PX4's preflight checks: the heading estimate settles a few seconds after boot."""
        return self._v.sim_time_s >= BOOT_HEALTHY_S

    def armable(self) -> bool:
        """PX4's pre-arm verdict (SYS_STATUS's PREARM_CHECK bit): it includes the selected mode's
        requirements, so OFFBOARD without a setpoint stream is not armable."""
        v = self._v
        if v.mode is FlightMode.OFFBOARD and not self.setpoints_fresh():
            return False
        return self.healthy() and v.battery_pct > 100.0 * v.params["BAT_CRIT_THR"]

    def _denied(self, text: str, result: int = mavlink.MAV_RESULT_DENIED) -> Result:
        return result, [Emit(self._v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL, text))]

    def arm(self, forced: bool, reason: str = "external command") -> Result:
        v = self._v
        if v.armed:
            return mavlink.MAV_RESULT_ACCEPTED, []
        if v.in_air:
            return mavlink.MAV_RESULT_DENIED, []  # a falling, disarmed vehicle does not re-arm
        if not forced:
            if not self.healthy():
                return self._denied("Arming denied: Resolve system health failures first",
                                    mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
            if v.mode in (FlightMode.LAND, FlightMode.RTL):
                return self._denied(f"Arming denied: {v.mode.name} mode is not armable")
            if v.mode is FlightMode.OFFBOARD and not self.setpoints_fresh():
                return self._denied("Arming denied: no offboard signal")
            if not self.armable():
                return self._denied("Arming denied: battery too low")
            violation = v.geofence.violation()
            if violation is not None:
                return self._denied(f"Arming denied: {violation}")
        v.armed = True
        self.armed_t = v.sim_time_s
        self.took_off_since_arm = False
        self.landed_t = None
        self.failsafe_t = None
        self.takeoff_start_t = v.sim_time_s if v.mode is FlightMode.TAKEOFF else None
        if v.mode is FlightMode.MISSION:
            v.nav.mission_enter()
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, f"Armed by {reason}"))]

    def disarm(self, forced: bool, reason: str) -> Result:
        v = self._v
        if not v.armed:
            return mavlink.MAV_RESULT_ACCEPTED, []
        if v.in_air and not forced:
            return self._denied("Disarming denied: not landed", mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
        v.armed = False
        self.armed_t = None
        self.failsafe_t = None
        self.takeoff_start_t = None
        v.physics.reset_land_detector()
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, f"Disarmed by {reason}"))]

    def on_takeoff_detected(self) -> None:
        self.landed_t = None
        if self._v.armed:
            self.took_off_since_arm = True

    def spooling_up(self) -> bool:
        """Armed and told to take off, but PX4 is not lifting yet (spool-up, take-off ramp)."""
        start = self.takeoff_start_t
        return start is None or self._v.sim_time_s < start + TAKEOFF_SPOOLUP_S

    # ---------------------------------------------------------------- modes --------------
    @property
    def loss_timeout_s(self) -> float:
        """COM_OF_LOSS_T in sim time: PX4 SITL multiplies its loss timeouts by the speed factor."""
        return self._v.params["COM_OF_LOSS_T"] * self._v.speed_factor

    def setpoints_fresh(self) -> bool:
        sp = self.setpoint
        return sp is not None and self._v.sim_time_s - sp.received_t_s <= self.loss_timeout_s

    def braking_point(self) -> tuple[float, float, float]:
        s = self._v.state
        speed = s.ground_speed_m_s
        if speed < 1e-3:
            return s.north_m, s.east_m, s.down_m
        k = speed / (2.0 * self._v.limits.max_accel_m_s2)  # v^2 / 2a along v, divided by v
        return s.north_m + s.vn_m_s * k, s.east_m + s.ve_m_s * k, s.down_m

    def request(self, mode: FlightMode, **targets) -> tuple[int, list[Emit]]:
        """A client asks for ``mode`` (DO_SET_MODE, SET_MODE): PX4 acks ACCEPTED even when it then
        refuses the switch, and only says so in a STATUSTEXT (the heartbeat tells the truth)."""
        if self.enter(mode, **targets) == mavlink.MAV_RESULT_ACCEPTED:
            self.failsafe_t = None  # the client took over
            return mavlink.MAV_RESULT_ACCEPTED, []
        text = f"Switching to {mode.name.capitalize()} is currently not available"
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL, text))]

    def enter(self, mode: FlightMode, *, takeoff_ned: tuple[float, float, float] | None = None,
              land_ne: tuple[float, float] | None = None) -> int:
        """Switch flight mode if PX4 would; returns the MAV_RESULT."""
        v = self._v
        nav = v.nav
        s = v.state
        if mode is FlightMode.OFFBOARD and v.armed and not self.setpoints_fresh():
            return mavlink.MAV_RESULT_DENIED  # disarmed, PX4 selects any mode; its requirements gate arming
        if mode is FlightMode.MISSION and not v.missions.plan(MISSION):
            return mavlink.MAV_RESULT_DENIED
        if mode is FlightMode.RTL and not v.in_air:
            return mavlink.MAV_RESULT_DENIED
        if mode is v.mode and mode not in (FlightMode.TAKEOFF, FlightMode.LAND):
            return mavlink.MAV_RESULT_ACCEPTED
        if mode in (FlightMode.LAND, FlightMode.RTL) and v.mode not in (FlightMode.LAND, FlightMode.RTL):
            self.mode_before_land = v.mode  # PX4 goes back to it after the landing disarm
        if mode in (FlightMode.HOLD, FlightMode.POSCTL):
            nav.hold_ned = self.braking_point()
        elif mode is FlightMode.TAKEOFF:
            nav.takeoff_target_ned = takeoff_ned or (s.north_m, s.east_m, -v.params["MIS_TAKEOFF_ALT"])
            if v.armed and not v.in_air and self.takeoff_start_t is None:
                self.takeoff_start_t = v.sim_time_s
        elif mode is FlightMode.LAND:
            nav.land_ne = land_ne or self.braking_point()[:2]
        elif mode is FlightMode.RTL:
            nav.rtl_phase = RtlPhase.CLIMB
            nav.hold_ned = self.braking_point()
        v.mode = mode
        if mode is FlightMode.MISSION:
            nav.mission_enter()
        return mavlink.MAV_RESULT_ACCEPTED

    # ---------------------------------------------------------------- offboard -----------
    def on_set_position_target_local_ned(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        v = self._v
        mask, frame = int(msg.type_mask), int(msg.coordinate_frame)
        use_pos = (mask & MASK_POSITION) == 0
        use_vel = (mask & MASK_VELOCITY) == 0
        partial = (0 < mask & MASK_POSITION < MASK_POSITION) or (0 < mask & MASK_VELOCITY < MASK_VELOCITY)
        body = frame in BODY_FRAMES
        valid_frame = body or frame in LOCAL_FRAMES
        values = ([msg.x, msg.y, msg.z] if use_pos else []) + ([msg.vx, msg.vy, msg.vz] if use_vel else [])
        yaw = None if mask & MASK_YAW or not math.isfinite(msg.yaw) else float(msg.yaw)
        yaw_rate = None if mask & MASK_YAW_RATE or not math.isfinite(msg.yaw_rate) else float(msg.yaw_rate)
        if (partial or not (use_pos or use_vel) or not valid_frame or (use_pos and body)
                or not all(math.isfinite(x) for x in values)):
            v.counters["invalid_setpoint"] += 1
            return []
        x, y, z = (float(msg.x), float(msg.y), float(msg.z)) if use_pos else (0.0, 0.0, 0.0)
        if use_pos and frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
            x, y, z = x + v.state.north_m, y + v.state.east_m, z + v.state.down_m
        self.setpoint = Setpoint(
            body=body, use_position=use_pos, x_m=x, y_m=y, z_m=z,
            vx_m_s=float(msg.vx) if use_vel else 0.0, vy_m_s=float(msg.vy) if use_vel else 0.0,
            vz_m_s=float(msg.vz) if use_vel else 0.0, yaw_rad=yaw, yaw_rate_rad_s=yaw_rate,
            received_t_s=v.sim_time_s)
        v.counters["setpoints"] += 1
        return []

    # ---------------------------------------------------------------- failsafes ----------
    def check(self, t: float) -> list[Emit]:
        """Per-step rules: boot messages, offboard loss and the return to OFFBOARD."""
        v = self._v
        out: list[Emit] = []
        if not self._boot_text_sent and t >= BOOT_PREFLIGHT_FAIL_S:
            self._boot_text_sent = True
            out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                                              "Preflight Fail: heading estimate not stable")))
        if not v.armed:
            return out
        sp = self.setpoint
        if v.mode is FlightMode.OFFBOARD:
            if sp is None or t - sp.received_t_s > self.loss_timeout_s:
                self.offboard_losses.append(OffboardLoss(sp.received_t_s if sp else -1.0, t))
                out += self._offboard_failsafe(t)
        elif self.failsafe_t is not None and sp is not None and sp.received_t_s > self.failsafe_t:
            # Setpoints are back: PX4 returns to the mode the client chose, by itself.
            self.failsafe_t = None
            self.enter(FlightMode.OFFBOARD)
        return out

    def _offboard_failsafe(self, t: float) -> list[Emit]:
        """COM_OBL_RC_ACT: 0-3 Return (without RC PX4 cannot fall back to a manual mode), 4 Land,
        5 Hold, 6-7 disarm. No extra heartbeat: clients see the mode at the next 1 Hz one."""
        v = self._v
        act = int(v.params["COM_OBL_RC_ACT"])
        self.failsafe_t = t
        out = [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated"))]
        if act >= 6:
            return out + self.disarm(True, "failsafe")[1]
        target = FlightMode.LAND if act == 4 else FlightMode.HOLD if act == 5 else FlightMode.RTL
        if target is FlightMode.RTL and not v.in_air:
            target = FlightMode.HOLD
        self.enter(target)
        if target is FlightMode.RTL:
            out.append(Emit(v.nav.rtl_start_text()))
        return out

    def check_auto_disarm(self, t: float) -> list[Emit]:
        v = self._v
        p = v.params
        if not v.armed or v.in_air:
            return []
        if self.landed_t is not None and p["COM_DISARM_LAND"] >= 0 and t - self.landed_t >= p["COM_DISARM_LAND"]:
            out = self.disarm(True, "landing")[1]
            if v.mode in (FlightMode.LAND, FlightMode.RTL) and self.mode_before_land is not None:
                v.mode = self.mode_before_land  # as PX4: back to the mode before the landing
            self.mode_before_land = None
            return out
        if (not self.took_off_since_arm and self.armed_t is not None and p["COM_DISARM_PRFLT"] >= 0
                and t - self.armed_t >= p["COM_DISARM_PRFLT"] + PRFLT_DISARM_LAG_S):
            return self.disarm(True, "auto preflight disarming")[1]
        return []
