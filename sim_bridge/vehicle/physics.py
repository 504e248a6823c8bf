"""One physics step: the plant, the land detector, collisions against the truth, the battery."""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink

from uav_model.plant import KinematicState
from sim_bridge.vehicle.energy import px4_sim_battery_pct
from sim_bridge.vehicle.collisions import CollisionChecker, CollisionEvent
from sim_bridge.vehicle.types import IN_AIR_ALT_M, LAND_DETECT_S, TAKEOFF_DETECT_S, TOUCHDOWN_ALT_M, Emit

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

log = logging.getLogger(__name__)

_BATTERY_WARNINGS = {1: ("Low battery level", mavlink.MAV_SEVERITY_WARNING),
                     2: ("Critical battery level", mavlink.MAV_SEVERITY_CRITICAL),
                     3: ("Emergency battery level", mavlink.MAV_SEVERITY_EMERGENCY)}


class Physics:
    """Moves the vehicle: the plant step and what follows from the new state."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        self._checker = CollisionChecker(v.world)
        self.collisions: list[CollisionEvent] = []
        self._inside: set[str] = set()
        self.accel_ned = (0.0, 0.0)
        self.drain_pct_s = 0.0
        self._battery_warned = 0  # 0 none, 1 low, 2 critical, 3 emergency
        self.takeoff_detected = False  # PX4's land detector: "in air" may come before lift-off
        self._touchdown_t: float | None = None

    def reset_land_detector(self) -> None:
        self.takeoff_detected = False

    def step(self, dt_s: float) -> list[Emit]:
        v = self._v
        out: list[Emit] = []
        t0 = v.sim_time_s
        t1 = t0 + dt_s
        old = v.state
        command = v.control.command(dt_s)
        if command is None:  # on the ground, not climbing: nothing moves
            new = KinematicState(old.north_m, old.east_m, old.down_m, yaw_rad=old.yaw_rad)
        else:
            new = v.plant_step(old, command, v.limits, dt_s)
        self.accel_ned = ((new.vn_m_s - old.vn_m_s) / dt_s, (new.ve_m_s - old.ve_m_s) / dt_s)
        v.state = new
        v.sim_time_s = t1
        v.steps += 1

        out += self._land_detector(t1)
        if v.in_air or -old.down_m > TOUCHDOWN_ALT_M:
            out += self._check_collisions(old, new, t0, t1)
        out += self._update_battery(dt_s)
        return out

    def _land_detector(self, t: float) -> list[Emit]:
        """Physical lift-off and touchdown, and PX4's land detector on top with its delays."""
        v = self._v
        s = v.state
        alt = -s.down_m
        out: list[Emit] = []
        if not v.in_air and alt > IN_AIR_ALT_M:
            v.in_air = True
            self._touchdown_t = None
            v.modes.on_takeoff_detected()
        elif v.in_air and alt <= TOUCHDOWN_ALT_M and s.vd_m_s >= -0.05:
            v.in_air = False
            self._touchdown_t = t
            v.state = replace(s, down_m=0.0, vn_m_s=0.0, ve_m_s=0.0, vd_m_s=0.0, yawspeed_rad_s=0.0)
        start = v.modes.takeoff_start_t
        if v.armed and not self.takeoff_detected and (
                v.in_air or (start is not None and t >= start + TAKEOFF_DETECT_S)):
            self.takeoff_detected = True
            v.modes.on_takeoff_detected()
            out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, "Takeoff detected")))
        if self._touchdown_t is not None and not v.in_air and t >= self._touchdown_t + LAND_DETECT_S:
            self._touchdown_t = None
            self.takeoff_detected = False
            v.modes.landed_t = t
            v.modes.takeoff_start_t = None
            out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, "Landing detected")))
        return out

    def _check_collisions(self, old: KinematicState, new: KinematicState, t0: float, t1: float) -> list[Emit]:
        v = self._v
        hits = self._checker.hits(old.east_m, old.north_m, new.east_m, new.north_m, t0, t1)
        out: list[Emit] = []
        for oid in hits:
            if oid not in self._inside:
                ev = CollisionEvent(t1, oid, new.east_m, new.north_m)
                self.collisions.append(ev)
                log.warning("%s: COLLISION with %s at t=%.2f s (%.1f, %.1f)", v.name, oid, t1, ev.x_m, ev.y_m)
                out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                                                  f"COLLISION {v.name} with {oid} t={t1:.1f}s")))
        self._inside = set(hits)
        return out

    def _update_battery(self, dt_s: float) -> list[Emit]:
        v = self._v
        s = v.state
        p = v.params
        if v.spec.battery_pct is None:  # the mission sets no charge: PX4 SITL's simulated battery
            before = v.battery_pct
            v.battery_pct = px4_sim_battery_pct(before, v.armed, dt_s, p["SIM_BAT_DRAIN"], p["SIM_BAT_MIN_PCT"])
            self.drain_pct_s = max(0.0, before - v.battery_pct) / dt_s
        else:
            self.drain_pct_s = v.energy.drain_pct_s(v.armed, v.in_air, s.ground_speed_m_s, -s.vd_m_s)
            v.battery_pct = max(0.0, v.battery_pct - self.drain_pct_s * dt_s)
        frac = v.battery_pct / 100.0
        level = (3 if frac <= p["BAT_EMERGEN_THR"] else 2 if frac <= p["BAT_CRIT_THR"]
                 else 1 if frac <= p["BAT_LOW_THR"] else 0)
        if level > self._battery_warned:
            self._battery_warned = level
            text, sev = _BATTERY_WARNINGS[level]
            return [Emit(v.tele.statustext(sev, f"{text}: {v.battery_pct:.0f}%"))]
        return []
