"""The navigator: the targets of the AUTO modes (take-off, hold, land, RTL) and mission flying."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import geodetic_to_local
from uav_model.plant import VelocityCommand
from sim_bridge.vehicle.mission_protocol import MISSION, NOOP_COMMANDS, RELATIVE_ALT_FRAMES, MissionItem, ProtocolEvent
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.vehicle.types import (
    LAND_POSITION_ACCEPT_M, MISSION_ALT_ACCEPT_M, Emit, MissionPhase, RtlPhase, clip,
)

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

NED = tuple[float, float, float]


class Navigator:
    """Where the AUTO modes fly to, and the mission item sequence."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        home = v.home_ned
        self.hold_ned: NED = home
        self.takeoff_target_ned: NED = home
        self.land_ne: tuple[float, float] = home[:2]
        self.rtl_phase = RtlPhase.CLIMB
        self.mission_index = 0
        self.mission_phase: MissionPhase | None = None
        self.mission_target: NED = home
        self.mission_hold_until: float | None = None
        self.mission_started = False
        self.mission_done = False
        self.mission_speed_m_s = v.params["MPC_XY_CRUISE"]

    def descending_to_land(self) -> bool:
        mode = self._v.mode
        return (mode is FlightMode.LAND or (mode is FlightMode.RTL and self.rtl_phase is RtlPhase.LAND)
                or (mode is FlightMode.MISSION and self.mission_phase is MissionPhase.LAND))

    # ---------------------------------------------------------------- per step -----------
    def update(self, t: float) -> list[Emit]:
        """Phase changes of the active AUTO mode after a physics step."""
        v = self._v
        s = v.state
        if v.mode is FlightMode.TAKEOFF and v.armed and v.in_air:
            if -s.down_m >= -self.takeoff_target_ned[2] - 0.2:
                v.modes.enter(FlightMode.HOLD)
                self.hold_ned = self.takeoff_target_ned
                return [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, "Takeoff complete"))]
        elif v.mode is FlightMode.MISSION and v.armed:
            return self._mission_update(t)
        elif v.mode is FlightMode.RTL and v.armed and v.in_air:
            return self._rtl_update()
        return []

    def _rtl_update(self) -> list[Emit]:
        v = self._v
        s = v.state
        rtl_alt = max(v.params["RTL_RETURN_ALT"], 0.5)
        if self.rtl_phase is RtlPhase.CLIMB and -s.down_m >= rtl_alt - MISSION_ALT_ACCEPT_M:
            self.rtl_phase = RtlPhase.RETURN
            self.hold_ned = (s.north_m, s.east_m, s.down_m)
        elif self.rtl_phase is RtlPhase.RETURN:
            if math.hypot(v.home_ned[0] - s.north_m, v.home_ned[1] - s.east_m) <= LAND_POSITION_ACCEPT_M:
                self.rtl_phase = RtlPhase.LAND
                return [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, "RTL: land at destination"))]
        return []

    def rtl_start_text(self) -> object:
        v = self._v
        rtl_alt = max(v.params["RTL_RETURN_ALT"], 0.5, -v.state.down_m)
        amsl = v.origin.alt_m - v.home_ned[2] + rtl_alt
        return v.tele.statustext(mavlink.MAV_SEVERITY_INFO,
                                 f"RTL: start return at {amsl:.0f} m ({rtl_alt:.0f} m above destination)")

    def rtl_command(self, dt_s: float) -> VelocityCommand | None:
        v = self._v
        if not v.in_air:
            return None
        ctl = v.control
        rtl_alt = max(v.params["RTL_RETURN_ALT"], 0.5)
        home_n, home_e, _ = v.home_ned
        cruise = v.params["MPC_XY_CRUISE"]
        if self.rtl_phase is RtlPhase.CLIMB:  # PX4 SIH: 25 -> 30 m in ~8 s, slowing near the top
            target = (self.hold_ned[0], self.hold_ned[1], min(-rtl_alt, v.state.down_m))
            return ctl.climb_approach(ctl.goto(target, cruise, dt_s), target[2])
        if self.rtl_phase is RtlPhase.RETURN:
            return ctl.goto((home_n, home_e, min(-rtl_alt, self.hold_ned[2])), cruise, dt_s, face_travel=True)
        return ctl.land_command(home_n, home_e, dt_s)

    # ---------------------------------------------------------------- mission ------------
    def on_plan_event(self, ev: ProtocolEvent) -> list[Emit]:
        v = self._v
        if ev.mission_type != MISSION:
            return []
        self.mission_index = 0
        self.mission_phase = None
        self.mission_started = False
        self.mission_done = False
        v.missions.current_seq = 0
        out = [Emit(v.tele.mission_current())]
        if v.mode is FlightMode.MISSION:
            if ev.kind == "cleared":
                v.modes.enter(FlightMode.HOLD)
                out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_WARNING, "Mission cleared: switching to Hold")))
            else:
                self.mission_enter()
        return out

    def set_mission_index(self, seq: int) -> None:
        self.mission_index = seq
        self.mission_phase = None
        self.mission_hold_until = None
        self.mission_done = False
        self._v.missions.current_seq = seq

    def mission_enter(self) -> None:
        plan = self._v.missions.plan(MISSION)
        if self.mission_done or self.mission_index >= len(plan):
            self.set_mission_index(0)
        self.mission_phase = None
        self.mission_started = True
        self.mission_speed_m_s = self._v.params["MPC_XY_CRUISE"]

    def _item_target_ned(self, item: MissionItem) -> NED:
        v = self._v
        s = v.state
        if item.command in (mavlink.MAV_CMD_NAV_TAKEOFF,) or (item.command == mavlink.MAV_CMD_NAV_LAND and item.x == 0 and item.y == 0):
            north, east = s.north_m, s.east_m
        else:
            x, y, _ = geodetic_to_local(v.origin, item.lat_deg, item.lon_deg)
            north, east = y, x
        rel = item.z if item.frame in RELATIVE_ALT_FRAMES else item.z - v.origin.alt_m
        if item.command == mavlink.MAV_CMD_NAV_LAND:
            return north, east, s.down_m
        return north, east, -clip(rel, 0.0, v.params.max_alt_m)

    def mission_command(self, dt_s: float) -> VelocityCommand | None:
        v = self._v
        ctl = v.control
        phase = self.mission_phase
        if phase is None or self.mission_done:
            return ctl.goto(self.hold_ned, v.limits.max_speed_m_s, dt_s) if v.in_air else None
        target = self.mission_target
        if phase is MissionPhase.TAKEOFF:
            return ctl.takeoff_command(target, 0.0, dt_s)
        if phase is MissionPhase.LAND:
            return ctl.land_command(target[0], target[1], dt_s)
        stop = phase is MissionPhase.HOLD or self._mission_stop_at_target()
        return ctl.goto(target, self.mission_speed_m_s, dt_s, stop=stop, face_travel=True)

    def _mission_stop_at_target(self) -> bool:
        plan = self._v.missions.plan(MISSION)
        item = plan[self.mission_index]
        if item.command != mavlink.MAV_CMD_NAV_WAYPOINT or item.param1 > 0:
            return True
        return not any(it.has_position for it in plan[self.mission_index + 1:])

    def _mission_update(self, t: float) -> list[Emit]:
        """Advance through the plan; done-at-once items chain within one step."""
        plan = self._v.missions.plan(MISSION)
        out: list[Emit] = []
        for _ in range(len(plan) + 1):
            if self.mission_done:
                return out
            if self.mission_index >= len(plan):
                return out + self._mission_finish("Mission finished")
            more, advance = self._mission_item_step(plan[self.mission_index], t)
            out += more
            if not advance:
                return out
            out += self._mission_advance()
        return out

    def _reached(self, item: MissionItem) -> Emit:
        return Emit(self._v.mav.mission_item_reached_encode(item.seq))

    def _mission_item_step(self, item: MissionItem, t: float) -> tuple[list[Emit], bool]:
        """One look at the current item: what to emit, and whether to advance to the next one."""
        v = self._v
        cmd = item.command
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self.mission_done = True
            v.modes.enter(FlightMode.RTL)
            return [self._reached(item), Emit(self.rtl_start_text())], False
        if cmd in NOOP_COMMANDS:
            if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0:
                self.mission_speed_m_s = min(item.param2, v.limits.max_speed_m_s)
            return [self._reached(item)], True
        if self.mission_phase is None:
            self._mission_item_begin(item)
            return [], False
        if self.mission_phase is MissionPhase.TAKEOFF:
            return self._mission_takeoff_step(item)
        if self.mission_phase is MissionPhase.GOTO:
            return self._mission_goto_step(item, t)
        if self.mission_phase is MissionPhase.HOLD:
            return [], self.mission_hold_until is not None and t >= self.mission_hold_until
        return self._mission_land_step(item)

    def _mission_item_begin(self, item: MissionItem) -> None:
        v = self._v
        s = v.state
        self.mission_target = self._item_target_ned(item)
        self.mission_hold_until = None
        if not v.in_air and item.command != mavlink.MAV_CMD_NAV_LAND:
            self.mission_phase = MissionPhase.TAKEOFF
            if v.modes.takeoff_start_t is None:
                v.modes.takeoff_start_t = v.sim_time_s
            if item.command != mavlink.MAV_CMD_NAV_TAKEOFF:  # implicit takeoff to the first waypoint's altitude
                self.mission_target = (s.north_m, s.east_m, self.mission_target[2])
        else:
            self.mission_phase = MissionPhase.GOTO

    def _mission_takeoff_step(self, item: MissionItem) -> tuple[list[Emit], bool]:
        v = self._v
        if -v.state.down_m >= -self.mission_target[2] - 0.5 and v.in_air:
            if item.command == mavlink.MAV_CMD_NAV_TAKEOFF:
                return [self._reached(item)], True
            self.mission_target = self._item_target_ned(item)
            self.mission_phase = MissionPhase.GOTO
        return [], False

    def _mission_goto_step(self, item: MissionItem, t: float) -> tuple[list[Emit], bool]:
        v = self._v
        s = v.state
        cmd = item.command
        target = self.mission_target
        acc = item.param2 if cmd == mavlink.MAV_CMD_NAV_WAYPOINT and item.param2 > 0 else v.params["NAV_ACC_RAD"]
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            acc = LAND_POSITION_ACCEPT_M
        dist = math.hypot(target[0] - s.north_m, target[1] - s.east_m)
        if dist > acc or (cmd != mavlink.MAV_CMD_NAV_LAND and abs(target[2] - s.down_m) > MISSION_ALT_ACCEPT_M):
            return [], False
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            self.mission_phase = MissionPhase.LAND
            return [], False
        if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
            self.mission_phase = MissionPhase.HOLD
            return [self._reached(item)], False
        hold = item.param1 if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME) else 0.0
        if hold > 0:
            self.mission_phase = MissionPhase.HOLD
            self.mission_hold_until = t + hold
            return [self._reached(item)], False
        return [self._reached(item)], True

    def _mission_land_step(self, item: MissionItem) -> tuple[list[Emit], bool]:
        v = self._v
        if v.in_air:
            return [], False
        self.mission_done = True  # PX4 stays in MISSION, landed and (soon) disarmed
        self.land_ne = (v.state.north_m, v.state.east_m)
        return [self._reached(item), Emit(v.tele.mission_current())], False

    def _mission_advance(self) -> list[Emit]:
        v = self._v
        n = len(v.missions.plan(MISSION))
        self.mission_index += 1
        self.mission_phase = None
        self.mission_hold_until = None
        v.missions.current_seq = min(self.mission_index, max(0, n - 1))
        return [Emit(v.tele.mission_current())] if self.mission_index < n else []

    def _mission_finish(self, text: str) -> list[Emit]:
        v = self._v
        self.mission_done = True
        out = [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, text)), Emit(v.tele.mission_current())]
        v.modes.enter(FlightMode.HOLD)
        if v.in_air and any(it.has_position for it in v.missions.plan(MISSION)):
            self.hold_ned = self.mission_target  # PX4 loiters at the last waypoint
        return out
