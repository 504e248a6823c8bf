"""MAV_CMDs through a dispatch table: a new command is one entry plus one method."""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any, Callable, Hashable

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import geodetic_to_local
from sim_bridge.vehicle.mission_protocol import MISSION, RELATIVE_ALT_FRAMES
from sim_bridge.vehicle.px4 import FlightMode, decode_custom_mode
from sim_bridge.vehicle.orbit import make_orbit
from sim_bridge.vehicle.types import FORCE_ARM_MAGIC, Command, Emit, Result

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

log = logging.getLogger(__name__)

GLOBAL_INT_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
                               mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


class Commands:
    """COMMAND_LONG / COMMAND_INT and the legacy SET_MODE, answered with one COMMAND_ACK each."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        self.table: dict[int, Callable[[Command, str, Hashable], Result]] = {
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_autopilot_capabilities,
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: self._get_message_interval,
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            mavlink.MAV_CMD_NAV_LAND: self._land,
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._rtl,
            mavlink.MAV_CMD_DO_SET_MODE: self._set_mode,
            mavlink.MAV_CMD_MISSION_START: self._mission_start,
            mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            mavlink.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            mavlink.MAV_CMD_DO_REPOSITION: self._reposition,
            mavlink.MAV_CMD_DO_ORBIT: self._orbit,
        }

    # ---------------------------------------------------------------- messages -----------
    def on_command_long(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        cmd = Command(int(msg.command), (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
                                         float(msg.param5), float(msg.param6), float(msg.param7)),
                      None, (msg.get_srcSystem(), msg.get_srcComponent()))
        return self.run(cmd, link, peer)

    def on_command_int(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        frame = int(msg.frame)
        scale = 1e-7 if frame in GLOBAL_INT_FRAMES else 1.0
        cmd = Command(int(msg.command), (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
                                         msg.x * scale, msg.y * scale, float(msg.z)),
                      frame, (msg.get_srcSystem(), msg.get_srcComponent()))
        return self.run(cmd, link, peer)

    def run(self, cmd: Command, link: str, peer: Hashable) -> list[Emit]:
        v = self._v
        handler = self.table.get(cmd.command)
        extra: list[Emit] = []
        if handler is None:
            result = mavlink.MAV_RESULT_UNSUPPORTED
            v.counters["command_unsupported"] += 1
        else:
            try:
                result, extra = handler(cmd, link, peer)
            except Exception:  # noqa: BLE001 - answer FAILED rather than stay silent
                log.exception("%s: command %d failed", v.name, cmd.command)
                v.counters["handler_error"] += 1
                result, extra = mavlink.MAV_RESULT_FAILED, []
            if result == mavlink.MAV_RESULT_DENIED:
                v.counters["command_denied"] += 1
        ack = v.mav.command_ack_encode(cmd.command, result, 0, 0, cmd.src[0], cmd.src[1])
        return [Emit(ack, link, peer)] + extra

    def on_set_mode(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        """Legacy SET_MODE message: acked as DO_SET_MODE, as PX4 does."""
        v = self._v
        main, sub = decode_custom_mode(int(msg.custom_mode))
        mode = FlightMode.from_px4(main, sub) if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
        result, extra = (mavlink.MAV_RESULT_DENIED, []) if mode is None else v.modes.request(mode)
        ack = v.mav.command_ack_encode(mavlink.MAV_CMD_DO_SET_MODE, result, 0, 0,
                                       msg.get_srcSystem(), msg.get_srcComponent())
        return [Emit(ack, link, peer)] + extra

    def on_mission_set_current(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        v = self._v
        plan = v.missions.plan(MISSION)
        if 0 <= msg.seq < len(plan):
            v.nav.set_mission_index(int(msg.seq))
        else:
            v.counters["bad_mission_set_current"] += 1
            return [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_WARNING, f"Mission item {msg.seq} does not exist"),
                         link, peer), Emit(v.tele.mission_current(), link, peer)]
        return [Emit(v.tele.mission_current())]

    def on_timesync(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        if msg.tc1 != 0:
            return []
        return [Emit(self._v.mav.timesync_encode(int(self._v.sim_time_s * 1e9), msg.ts1), link, peer)]

    # ---------------------------------------------------------------- streams ------------
    def _request_message(self, cmd: Command, link: str, peer: Hashable) -> Result:
        msg_id = cmd.params[0]
        if not math.isfinite(msg_id) or msg_id < 0 or msg_id != int(msg_id):
            return mavlink.MAV_RESULT_DENIED, []
        builder = self._v.tele.builders.get(int(msg_id))
        if builder is None:
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(m, link, peer) for m in builder()]

    def _request_autopilot_capabilities(self, cmd: Command, link: str, peer: Hashable) -> Result:
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._v.tele.autopilot_version(), link, peer)]

    def _set_message_interval(self, cmd: Command, link: str, peer: Hashable) -> Result:
        tele = self._v.tele
        msg_id, interval_us = cmd.params[0], cmd.params[1]
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)) or msg_id < 0 or interval_us < -1:
            return mavlink.MAV_RESULT_DENIED, []
        if int(msg_id) not in tele.builders or int(msg_id) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        sched = tele.links.get(link)
        if sched is None:
            return mavlink.MAV_RESULT_FAILED, []
        if interval_us == -1:
            sched.set_interval(int(msg_id), None)
        elif interval_us == 0:
            sched.reset_default(int(msg_id))
        else:
            sched.set_interval(int(msg_id), max(interval_us, 1000.0) / 1e6)
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _get_message_interval(self, cmd: Command, link: str, peer: Hashable) -> Result:
        tele = self._v.tele
        msg_id = cmd.params[0]
        if not math.isfinite(msg_id) or msg_id < 0 or msg_id > 2**24:
            return mavlink.MAV_RESULT_DENIED, []
        sched = tele.links.get(link)
        if int(msg_id) not in tele.builders or sched is None:
            interval_us = 0  # "not available"
        else:
            interval = sched.interval_s(int(msg_id))
            interval_us = -1 if interval is None else int(round(interval * 1e6))
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._v.mav.message_interval_encode(int(msg_id), interval_us),
                                                  link, peer)]

    # ---------------------------------------------------------------- flight -------------
    def _arm_disarm(self, cmd: Command, link: str, peer: Hashable) -> Result:
        arm, force = cmd.params[0], cmd.params[1]
        forced = force == FORCE_ARM_MAGIC
        if arm == 1.0:
            return self._v.modes.arm(forced)
        if arm == 0.0:
            return self._v.modes.disarm(forced, "external command")
        return mavlink.MAV_RESULT_DENIED, []

    def _relative_alt(self, cmd: Command, alt: float) -> float:
        """COMMAND_LONG altitude is AMSL (MAV_FRAME_GLOBAL); COMMAND_INT says its frame."""
        return alt if cmd.frame in RELATIVE_ALT_FRAMES else alt - self._v.origin.alt_m

    def _commanded(self, mode: FlightMode, **targets) -> int:
        """A mode a command implies (take-off, land, return): the client takes over from a failsafe."""
        result = self._v.modes.enter(mode, **targets)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self._v.modes.failsafe_t = None
        return result

    def _takeoff(self, cmd: Command, link: str, peer: Hashable) -> Result:
        v = self._v
        yaw_deg, alt = cmd.params[3], cmd.params[6]
        rel = self._relative_alt(cmd, alt) if math.isfinite(alt) else v.params["MIS_TAKEOFF_ALT"]
        if not (0.5 <= rel <= v.params.max_alt_m) or math.isinf(yaw_deg):  # NaN yaw: keep the heading
            return mavlink.MAV_RESULT_DENIED, []
        s = v.state
        result = self._commanded(FlightMode.TAKEOFF, takeoff_ned=(s.north_m, s.east_m, -rel))
        extra = [] if math.isfinite(alt) else [Emit(v.tele.statustext(
            mavlink.MAV_SEVERITY_INFO, f"Using default takeoff altitude: {rel:.1f} m"))]
        return result, extra

    def _land(self, cmd: Command, link: str, peer: Hashable) -> Result:
        v = self._v
        lat, lon = cmd.params[4], cmd.params[5]
        land_ne = None
        if math.isfinite(lat) and math.isfinite(lon) and not (lat == 0.0 and lon == 0.0):
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                return mavlink.MAV_RESULT_DENIED, []
            x, y, _ = geodetic_to_local(v.origin, lat, lon)
            land_ne = (y, x)
        text = "Landing at current position" if land_ne is None else "Landing at the commanded position"
        return self._commanded(FlightMode.LAND, land_ne=land_ne), [
            Emit(v.tele.statustext(mavlink.MAV_SEVERITY_INFO, text))]

    def _rtl(self, cmd: Command, link: str, peer: Hashable) -> Result:
        result = self._commanded(FlightMode.RTL)
        return result, [Emit(self._v.nav.rtl_start_text())] if result == mavlink.MAV_RESULT_ACCEPTED else []

    def _set_mode(self, cmd: Command, link: str, peer: Hashable) -> Result:
        base, main, sub = cmd.params[0], cmd.params[1], cmd.params[2]
        if not all(math.isfinite(x) for x in (base, main)):
            return mavlink.MAV_RESULT_DENIED, []
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED, []  # PX4 modes are custom modes
        sub_i = int(sub) if math.isfinite(sub) else 0
        mode = FlightMode.from_px4(int(main), sub_i)
        if mode is None:
            return mavlink.MAV_RESULT_DENIED, []
        return self._v.modes.request(mode)

    # ---------------------------------------------------------------- mission ------------
    def _mission_start(self, cmd: Command, link: str, peer: Hashable) -> Result:
        v = self._v
        first = cmd.params[0]
        plan = v.missions.plan(MISSION)
        if math.isfinite(first) and first > 0:
            if first != int(first) or first >= len(plan):
                return mavlink.MAV_RESULT_DENIED, []
            v.nav.set_mission_index(int(first))
        result = self._commanded(FlightMode.MISSION)
        if result != mavlink.MAV_RESULT_ACCEPTED or v.armed:
            return result, []
        return v.modes.arm(False, "mission start")  # PX4 arms a disarmed vehicle on MISSION_START

    def _set_mission_current(self, cmd: Command, link: str, peer: Hashable) -> Result:
        v = self._v
        seq = cmd.params[0]
        plan = v.missions.plan(MISSION)
        if not math.isfinite(seq) or seq != int(seq) or not 0 <= seq < max(1, len(plan)):
            return mavlink.MAV_RESULT_DENIED, []
        v.nav.set_mission_index(int(seq))
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(v.tele.mission_current())]

    def _change_speed(self, cmd: Command, link: str, peer: Hashable) -> Result:
        speed = cmd.params[1]
        if not math.isfinite(speed) or speed > 1000.0:
            return mavlink.MAV_RESULT_DENIED, []
        if speed > 0:
            self._v.nav.mission_speed_m_s = min(speed, self._v.limits.max_speed_m_s)
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _reposition(self, cmd: Command, link: str, peer: Hashable) -> Result:
        """Go to a point and hold there (PX4: DO_REPOSITION switches to Hold at the target)."""
        v = self._v
        lat, lon, alt = cmd.params[4], cmd.params[5], cmd.params[6]
        if not (v.armed and v.in_air):
            return mavlink.MAV_RESULT_DENIED, []
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            return mavlink.MAV_RESULT_DENIED, []
        x, y, _ = geodetic_to_local(v.origin, lat, lon)
        rel = self._relative_alt(cmd, alt) if math.isfinite(alt) else -v.state.down_m
        if not 0.0 <= rel <= v.params.max_alt_m:
            return mavlink.MAV_RESULT_DENIED, []
        result = self._commanded(FlightMode.HOLD)
        v.nav.hold_ned = (y, x, -rel)
        return result, []

    def _orbit(self, cmd: Command, link: str, peer: Hashable) -> Result:
        """Fly a circle (PX4's ORBIT mode); in the air only."""
        v = self._v
        radius, speed, yaw, _, lat, lon, alt = cmd.params
        if not (v.armed and v.in_air):
            return mavlink.MAV_RESULT_DENIED, []
        center = None
        if math.isfinite(lat) and math.isfinite(lon):
            if not (-90 <= lat <= 90 and -180 <= lon <= 180):
                return mavlink.MAV_RESULT_DENIED, []
            x, y, _ = geodetic_to_local(v.origin, lat, lon)
            center = (y, x)
        down = -self._relative_alt(cmd, alt) if math.isfinite(alt) else None
        orbit = make_orbit(v.state, radius, speed, yaw, center, down, v.params["MC_ORBIT_RAD_MAX"])
        if orbit is None or (down is not None and not 0.0 <= -down <= v.params.max_alt_m):
            return mavlink.MAV_RESULT_DENIED, []
        v.orbit = orbit
        return self._commanded(FlightMode.ORBIT), []
