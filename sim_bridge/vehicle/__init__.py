"""One simulated vehicle: a PX4-like state machine over the kinematic plant. Sans-I/O.

``SimVehicle`` consumes decoded MAVLink messages and sim time, and emits MAVLink messages
(pymavlink objects, used as the codec's value types) tagged with where they go. It owns no
socket, no clock and no event loop, so every rule here is testable by calling methods:

    handle(msg, link, peer)   -> [Emit]   a message arrived on a link (replies go back there)
    step(dt_s)                -> [Emit]   advance physics and flight logic by one sim step
    telemetry(wall_t)         -> [Emit]   the streamed messages due on each link
    poll(wall_t)              -> [Emit]   wall-clock duties (mission transfer retries)

The facade holds the state every part shares (kinematic state, sim time, armed, mode, in-air,
battery) and routes to its parts, one concern each:

    commands.Commands     MAV_CMD dispatch table, SET_MODE, TIMESYNC
    params.ParamStore     PX4-named parameters and the parameter protocol
    modes.Modes           arming, mode switching rules, offboard setpoints, failsafes
    navigator.Navigator   AUTO-mode targets: take-off, hold, land, RTL, mission items
    control.Controller    the velocity command each mode asks of the plant
    physics.Physics       the plant step, land detector, collisions, battery
    geofence.Geofence     the stored FENCE plan, its breach check and GF_ACTION
    telemetry.Telemetry   message builders and per-link stream schedulers

Frames: the plant and every MAVLink field are in PX4's local NED frame, whose origin is the
mission's geodetic origin for all vehicles (a shared EKF origin), so LOCAL_POSITION_NED of
either vehicle is directly comparable and maps to mission ENU through :mod:`uav_model.frames`.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Callable, Hashable, Mapping

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import enu_heading_to_ned_yaw
from uav_model.mission import Mission, VehicleSpec
from uav_model.plant import KinematicState, Plant, PlantLimits, step_for
from sim_bridge.energy import EnergyModel
from sim_bridge.mission_protocol import MissionProtocol
from sim_bridge.px4 import FlightMode, default_params
from sim_bridge.streams import API_PROFILE, StreamProfile
from sim_bridge.truth import CollisionEvent
from sim_bridge.vehicle.commands import Commands
from sim_bridge.vehicle.control import Controller
from sim_bridge.vehicle.geofence import Geofence
from sim_bridge.vehicle.modes import Modes
from sim_bridge.vehicle.navigator import Navigator
from sim_bridge.vehicle.orbit import Orbit
from sim_bridge.vehicle.params import ParamStore
from sim_bridge.vehicle.physics import Physics
from sim_bridge.vehicle.telemetry import ADSB_ICAO_BASE, Telemetry
from sim_bridge.vehicle.types import AUTOPILOT_COMPONENT_ID, Emit, LandedState, OffboardLoss, Setpoint

__all__ = ["ADSB_ICAO_BASE", "Emit", "LandedState", "OffboardLoss", "Setpoint", "SimVehicle"]

log = logging.getLogger(__name__)

_IGNORED = frozenset({"HEARTBEAT", "REQUEST_DATA_STREAM", "SYSTEM_TIME", "PING"})


class SimVehicle:
    """A PX4-like multicopter: modes, arming, offboard, missions, params, telemetry, truth."""

    def __init__(self, spec: VehicleSpec, mission: Mission, *, speed_headroom: float = 1.0,
                 energy: EnergyModel | None = None, component_id: int = AUTOPILOT_COMPONENT_ID,
                 speed_factor: float = 1.0, params: Mapping[str, float] | None = None):
        self.spec = spec
        self.name = spec.name
        self.system_id = spec.system_id
        self.component_id = component_id
        self.origin = mission.origin
        self.world = mission.world
        self.energy = energy or EnergyModel()
        self.mav = mavlink.MAVLink(None, self.system_id, component_id)  # message factory only
        self.missions = MissionProtocol(self.system_id, component_id, self.mav)
        self.counters: Counter[str] = Counter()
        self._wall_t = 0.0  # last wall time the I/O layer reported (mission transfer timing)

        # The unicycle flies the mission's limits (an airframe tuned for it); the multicopter PX4's defaults.
        defs = default_params(self.system_id, spec.speed_m_s * speed_headroom, spec.max_yaw_rate_rad_s,
                              spec.max_accel_m_s2, spec.cruise_alt_m, mission_tuned=mission.plant is Plant.UNICYCLE)
        self.plant = mission.plant
        self.plant_step = step_for(mission.plant)  # the one pure step the vehicle flies (uav_model.plant)
        self.params = ParamStore(self, defs, max_alt_m=max(500.0, 2.0 * spec.cruise_alt_m), plant=mission.plant)
        for name, value in (params or {}).items():
            self.params.override(name, value)
        self.speed_factor = speed_factor  # sim s per wall s, as PX4_SIM_SPEED_FACTOR: scales loss timeouts

        home_x, home_y = spec.start_enu_m
        self.home_ned = (home_y, home_x, 0.0)
        self.sim_time_s = 0.0
        self.steps = 0
        self.state = KinematicState(north_m=home_y, east_m=home_x, down_m=0.0,
                                    yaw_rad=enu_heading_to_ned_yaw(spec.spawn_heading_rad))
        self.armed = False
        self.mode = FlightMode.HOLD
        self.in_air = False
        self.orbit: Orbit | None = None  # the last DO_ORBIT, flown in FlightMode.ORBIT
        self.battery_pct = 100.0 if spec.battery_pct is None else float(spec.battery_pct)

        self.tele = Telemetry(self)
        self.modes = Modes(self)
        self.nav = Navigator(self)
        self.control = Controller(self)
        self.physics = Physics(self)
        self.commands = Commands(self)
        self.geofence = Geofence(self)
        self._handlers: dict[str, Callable[[Any, str, Hashable], list[Emit]]] = {
            "COMMAND_LONG": self.commands.on_command_long,
            "COMMAND_INT": self.commands.on_command_int,
            "SET_POSITION_TARGET_LOCAL_NED": self.modes.on_set_position_target_local_ned,
            "SET_MODE": self.commands.on_set_mode,
            "PARAM_SET": self.params.on_param_set,
            "PARAM_REQUEST_READ": self.params.on_param_request_read,
            "PARAM_REQUEST_LIST": self.params.on_param_request_list,
            "MISSION_SET_CURRENT": self.commands.on_mission_set_current,
            "TIMESYNC": self.commands.on_timesync,
        }

    # ================================================================== public state ======
    @property
    def limits(self) -> PlantLimits:
        return self.params.limits

    @property
    def landed_state(self) -> LandedState:
        if not (self.in_air or self.physics.takeoff_detected):
            return LandedState.ON_GROUND
        if self.armed and self.mode is FlightMode.TAKEOFF:
            return LandedState.TAKEOFF
        if self.armed and self.nav.descending_to_land():
            return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def position_enu_m(self) -> tuple[float, float, float]:
        s = self.state
        return s.east_m, s.north_m, -s.down_m

    @property
    def collisions(self) -> list[CollisionEvent]:
        return self.physics.collisions

    @property
    def collision_count(self) -> int:
        return len(self.physics.collisions)

    @property
    def offboard_losses(self) -> list[OffboardLoss]:
        return self.modes.offboard_losses

    @property
    def mission_index(self) -> int:
        return self.nav.mission_index

    @property
    def mission_finished(self) -> bool:
        return self.nav.mission_done

    @property
    def setpoint(self) -> Setpoint | None:
        return self.modes.setpoint

    def param(self, name: str) -> float:
        return self.params[name]

    def add_link(self, link: str, profile: StreamProfile = API_PROFILE) -> None:
        """Register a link: its streams start at the profile's default rates."""
        self.tele.add_link(link, profile)

    def link_interval_s(self, link: str, msg_id: int) -> float | None:
        return self.tele.links[link].interval_s(msg_id)

    # ================================================================== input =============
    def handle(self, msg: Any, link: str, peer: Hashable = None) -> list[Emit]:
        """React to one decoded message from ``link``/``peer``. Never raises."""
        try:
            return self._handle(msg, link, peer)
        except Exception:  # noqa: BLE001 - a bad message must never take the vehicle down
            self.counters["handler_error"] += 1
            log.exception("%s: error handling %s", self.name, getattr(msg, "get_type", lambda: "?")())
            return []

    def _handle(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        name = msg.get_type()
        if name == "BAD_DATA":
            self.counters["bad_data"] += 1
            return []
        target = getattr(msg, "target_system", None)
        if target is not None and target not in (0, self.system_id):
            self.counters["wrong_target"] += 1
            return []
        comp = getattr(msg, "target_component", None)
        if comp is not None and comp not in (0, self.component_id):
            self.counters["other_component"] += 1
            return []
        handler = self._handlers.get(name)
        if handler is not None:
            return handler(msg, link, peer)
        if name.startswith("MISSION_"):
            replies, events = self.missions.handle(msg, link, peer, self._wall_t)
            out = [Emit(r.msg, r.link, r.peer) for r in replies]
            for ev in events:
                out += self.nav.on_plan_event(ev)
            return out
        if name not in _IGNORED:
            self.counters["unhandled"] += 1
        return []

    def poll(self, wall_t: float) -> list[Emit]:
        """Wall-clock duties; call often (every loop iteration)."""
        self._wall_t = wall_t
        return [Emit(r.msg, r.link, r.peer) for r in self.missions.poll(wall_t)]

    # ================================================================== time ==============
    def step(self, dt_s: float) -> list[Emit]:
        """Advance one physics step of ``dt_s`` sim seconds. Never raises."""
        try:
            out = self.physics.step(dt_s)
            t = self.sim_time_s
            out += self.modes.check(t)
            out += self.geofence.check(t)
            out += self.nav.update(t)
            return out + self.modes.check_auto_disarm(t)
        except Exception:  # noqa: BLE001 - keep flying (time still advances) and say so
            self.counters["step_error"] += 1
            if self.counters["step_error"] <= 5:
                log.exception("%s: error in physics step at t=%.2f", self.name, self.sim_time_s)
            self.sim_time_s += dt_s
            return []

    # ================================================================== output ============
    def telemetry(self, wall_t: float) -> list[Emit]:
        """Streamed messages due now on every link."""
        return self.tele.due(wall_t)

    def build(self, msg_id: int) -> list[Any]:
        """The message(s) the vehicle would send for ``msg_id`` now (empty if it cannot)."""
        return self.tele.build(msg_id)
