"""Controllers: the velocity command each mode asks of the plant (PX4's position controller, simplified)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from uav_model.frames import wrap_pi
from uav_model.plant import HOVER, VelocityCommand, VelocityFrame
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.vehicle.orbit import orbit_command
from sim_bridge.vehicle.types import (
    KP_ALTITUDE_1_S, KP_POSITION_1_S, TAKEOFF_APPROACH_KP_1_S, TAKEOFF_FAST_FRACTION, TAKEOFF_RAMP, TAKEOFF_SPOOLUP_S,
    TOUCHDOWN_ALT_M, clip,
)

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

NED = tuple[float, float, float]


class Controller:
    """Turns the active mode's target into a VelocityCommand for the plant."""

    def __init__(self, v: "SimVehicle"):
        self._v = v

    def yawspeed_toward(self, yaw_target: float, dt_s: float) -> float:
        """Auto-mode yaw: P on the angle (dead-beat on the unicycle), within MPC_YAWRAUTO_MAX. On a
        lagging heading rate the angle the rate will still turn (rate x lag) counts as turned, so a
        fast turn brakes in time instead of swinging past (PX4's yaw trajectory does the same)."""
        v = self._v
        lim = v.limits
        err = wrap_pi(yaw_target - v.state.yaw_rad) - v.state.yawspeed_rad_s * lim.yaw_lag_s
        rate = math.radians(v.params["MPC_YAWRAUTO_MAX"])
        return clip(err * min(1.0 / dt_s, lim.yaw_p_1_s), -rate, rate)

    def goto(self, target: NED, speed_m_s: float, dt_s: float, *, stop: bool = True, yaw_rad: float | None = None,
             face_travel: bool = False, climb_m_s: float | None = None) -> VelocityCommand:
        """Velocity toward a NED point: cruise, brake to stop on it, altitude by P control."""
        v = self._v
        s = v.state
        lim = v.limits
        dn, de = target[0] - s.north_m, target[1] - s.east_m
        dist = math.hypot(dn, de)
        speed = min(speed_m_s, lim.max_speed_m_s)
        if stop:
            speed = min(speed, math.sqrt(1.6 * lim.max_accel_m_s2 * dist), KP_POSITION_1_S * dist)
        vn, ve = (dn / dist * speed, de / dist * speed) if dist > 1e-6 else (0.0, 0.0)
        up = v.params["MPC_Z_VEL_MAX_UP"] if climb_m_s is None else climb_m_s
        vd = clip(KP_ALTITUDE_1_S * (target[2] - s.down_m), -up, v.params["MPC_Z_VEL_MAX_DN"])
        if yaw_rad is None and face_travel and dist > 2.0:
            yaw_rad = math.atan2(de, dn)
        yawspeed = 0.0 if yaw_rad is None else self.yawspeed_toward(yaw_rad, dt_s)
        return VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, vd, yawspeed)

    def takeoff_command(self, target: NED, speed_m_s: float, dt_s: float) -> VelocityCommand | None:
        """PX4's take-off, as measured on SIH: on the ground through the spool-up, a ramp up to
        MPC_TKO_SPEED, that climb rate up to TAKEOFF_FAST_FRACTION of the altitude, then the position
        controller's approach (up to MPC_Z_VEL_MAX_UP, slowing near the top)."""
        v = self._v
        if not v.in_air and v.modes.spooling_up():
            return None
        p = v.params
        if -v.state.down_m < -TAKEOFF_FAST_FRACTION * target[2]:
            start = v.modes.takeoff_start_t
            first, ramp_s = TAKEOFF_RAMP
            ramp = 1.0 if start is None else first + (1.0 - first) * (v.sim_time_s - start - TAKEOFF_SPOOLUP_S) / ramp_s
            climb = p["MPC_TKO_SPEED"] * clip(ramp, first, 1.0)
            return self.goto(target, speed_m_s, dt_s, climb_m_s=climb)
        return self.climb_approach(self.goto(target, speed_m_s, dt_s), target[2])

    def climb_approach(self, cmd: VelocityCommand, target_down_m: float) -> VelocityCommand:
        """``cmd`` with PX4's auto-mode approach to an altitude (take-off's upper part, RTL's climb):
        TAKEOFF_APPROACH_KP_1_S per metre to go, within MPC_Z_VEL_MAX_UP / DN."""
        p = self._v.params
        vd = clip(TAKEOFF_APPROACH_KP_1_S * (target_down_m - self._v.state.down_m), -p["MPC_Z_VEL_MAX_UP"],
                  p["MPC_Z_VEL_MAX_DN"])
        return replace(cmd, z_m_s=vd)

    def track(self, target: NED, feed_forward: NED) -> VelocityCommand:
        """PX4's position controller with a velocity feed-forward: v = v_ff + Kp (p_sp - p), limited."""
        s = self._v.state
        lim = self._v.limits
        vn = feed_forward[0] + KP_POSITION_1_S * (target[0] - s.north_m)
        ve = feed_forward[1] + KP_POSITION_1_S * (target[1] - s.east_m)
        speed = math.hypot(vn, ve)
        if speed > lim.max_speed_m_s:
            vn, ve = vn * lim.max_speed_m_s / speed, ve * lim.max_speed_m_s / speed
        vd = clip(feed_forward[2] + KP_ALTITUDE_1_S * (target[2] - s.down_m), -self._v.params["MPC_Z_VEL_MAX_UP"],
                  self._v.params["MPC_Z_VEL_MAX_DN"])
        return VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, vd, 0.0)

    def land_command(self, north_m: float, east_m: float, dt_s: float) -> VelocityCommand:
        v = self._v
        p = v.params
        alt = -v.state.down_m
        fast, slow = p["MPC_Z_VEL_MAX_DN"], p["MPC_LAND_SPEED"]
        hi, lo = p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"]
        if alt <= p["MPC_LAND_ALT3"]:
            vd = min(slow, p["MPC_LAND_CRWL"])  # the last metre at crawl speed, as PX4 SIH touches down
        elif alt >= hi:
            vd = fast
        elif alt > lo and hi > lo:
            vd = slow + (fast - slow) * (alt - lo) / (hi - lo)
        else:
            vd = slow
        cmd = self.goto((north_m, east_m, v.state.down_m), v.limits.max_speed_m_s, dt_s)
        return replace(cmd, z_m_s=vd)

    def offboard_command(self, dt_s: float) -> VelocityCommand:
        sp = self._v.modes.setpoint
        if sp is None:
            return HOVER
        if sp.yaw_rate_rad_s is not None:
            yawspeed = sp.yaw_rate_rad_s
        elif sp.yaw_rad is not None:
            yawspeed = self.yawspeed_toward(sp.yaw_rad, dt_s)
        else:
            yawspeed = 0.0
        if sp.use_position and (sp.vx_m_s, sp.vy_m_s, sp.vz_m_s) != (0.0, 0.0, 0.0):
            cmd = self.track((sp.x_m, sp.y_m, sp.z_m), (sp.vx_m_s, sp.vy_m_s, sp.vz_m_s))
            return replace(cmd, yawspeed_rad_s=yawspeed)
        if sp.use_position:
            cmd = self.goto((sp.x_m, sp.y_m, sp.z_m), self._v.limits.max_speed_m_s, dt_s, yaw_rad=sp.yaw_rad)
            return replace(cmd, yawspeed_rad_s=yawspeed)
        frame = VelocityFrame.BODY_NED if sp.body else VelocityFrame.LOCAL_NED
        return VelocityCommand(frame, sp.vx_m_s, sp.vy_m_s, sp.vz_m_s, yawspeed)

    def _mode_command(self, dt_s: float) -> VelocityCommand | None:
        v = self._v
        nav = v.nav
        mode = v.mode
        if mode is FlightMode.OFFBOARD:
            return self.offboard_command(dt_s)
        if mode in (FlightMode.HOLD, FlightMode.POSCTL):
            return self.goto(nav.hold_ned, v.limits.max_speed_m_s, dt_s) if v.in_air else None
        if mode is FlightMode.TAKEOFF:
            return self.takeoff_command(nav.takeoff_target_ned, 0.0 if not v.in_air else v.limits.max_speed_m_s,
                                        dt_s)
        if mode is FlightMode.LAND:
            return self.land_command(*nav.land_ne, dt_s) if v.in_air else None
        if mode is FlightMode.MISSION:
            return nav.mission_command(dt_s)
        if mode is FlightMode.RTL:
            return nav.rtl_command(dt_s)
        if mode is FlightMode.ORBIT:
            return orbit_command(v.orbit, v.state, v.limits, dt_s) if v.orbit is not None else HOVER
        return HOVER  # pragma: no cover - every FlightMode is handled above

    def command(self, dt_s: float) -> VelocityCommand | None:
        """The velocity command of the active mode, or None for "stay put on the ground"."""
        v = self._v
        if not v.armed:
            if v.in_air:  # disarmed in the air (forced): motors off, it drops
                return VelocityCommand(VelocityFrame.LOCAL_NED, 0.0, 0.0, v.limits.max_climb_m_s, 0.0)
            return None
        cmd = self._mode_command(dt_s)
        if cmd is None:
            return None
        if not v.in_air and v.state.down_m >= -TOUCHDOWN_ALT_M and cmd.z_m_s >= 0.0:
            return None  # on the ground and not climbing: no sliding about
        return cmd
