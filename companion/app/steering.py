"""One pilot's steering: a planner tick from a pose, the setpoint it becomes after the safety
monitors, and the flight log's row for it. Mixed into :class:`companion.app.pilot.Pilot`.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np

from uav_model import frames
from companion.app import monitors
from companion.planning.dwa import OtherUav, Pose, inflated_clearance
from companion.planning.fleet import Neighbour, Reaction, react_to
from companion.planning.obstacle_field import ObstacleSnapshot, ObstacleTrack
from companion.planning.vehicle_planner import TickResult
from companion.errors import CommandRefused, TelemetryLost
from companion.vehicle.port import HOVER, LandedState, PoseSample, TrafficReport, VelocityYawRateSetpoint

if TYPE_CHECKING:
    from uav_model.mission import VehicleSpec
    from companion.app.context import FlightContext, PilotOutcome
    from companion.planning.vehicle_planner import VehiclePlanner
    from companion.vehicle.port import Vehicle


def clearance_here_m(x_m: float, y_m: float, snapshot: ObstacleSnapshot) -> float:
    """Clearance (m) of the point (x, y) to the inflated obstacles of ``snapshot`` (the log's column)."""
    clearance = inflated_clearance(np.array([x_m]), np.array([y_m]), np.zeros(1), snapshot)
    return float(clearance.min()) if clearance.size else math.inf


class Steering:
    """Tick, setpoint and log of one vehicle (needs the Pilot's ctx, spec, vehicle, planner, outcome)."""

    ctx: FlightContext
    spec: VehicleSpec
    name: str
    vehicle: Vehicle
    planner: VehiclePlanner
    outcome: PilotOutcome
    _next_progress_s: float
    _t_plan: float  # the schedule time of the last tick (the timed route is read at it)
    setpoint: VelocityYawRateSetpoint  # what the keep-alive streams

    def _at_station(self, pose: PoseSample) -> bool:
        sx, sy = self.planner.station_xy
        return math.hypot(pose.x_east_m - sx, pose.y_north_m - sy) <= self.planner.arrival_radius_m

    async def _hover(self) -> None:
        """Hover from now on (the keep-alive streams it), sent at once. At the station it brakes
        before the HOLD command, which a lossy link may delay by seconds of wall time: at 20x with
        5 % loss a vehicle flew on at its last cruise setpoint 120 m past its station, out of
        the fence, before HOLD took."""
        self.setpoint = HOVER
        try:
            await self.vehicle.send_setpoint(HOVER)
        except CommandRefused:
            pass  # the keep-alive resends it; a dead link shows as stale telemetry

    def _mission_time(self, pose: PoseSample) -> float:
        """Sim seconds since this vehicle's own departure (the time limit's and the watchdog's clock)."""
        return pose.t_sim_s - (self.outcome.t_depart_sim_s or pose.t_sim_s)

    def _tick(self, pose: PoseSample) -> TickResult:
        own = Pose(pose.x_east_m, pose.y_north_m, pose.heading_enu_rad, pose.vx_east_m_s, pose.vy_north_m_s)
        self._snapshot = self.ctx.field.from_tracks(self._obstacle_tracks(pose))
        self._t_plan = self.ctx.schedule_time(self, pose)
        reaction = self._reaction(pose)
        result = self.planner.tick(own, reaction.other, self._snapshot, self._mission_time(pose), self._t_plan,
                                   separate_from=reaction.separate_from)
        self.outcome.ticks += 1
        if not result.arrived:
            self.outcome.planner_ms.append(result.planner_ms)
        return result

    def _age_s(self, at: PoseSample, t_sim_s: float, t_wall_s: float, same_link: bool) -> float:
        """How old (sim seconds) a report stamped (t_sim, t_wall) is at the pose ``at``."""
        if same_link or self.ctx.shared_clock:
            age = at.t_sim_s - t_sim_s
        else:
            age = (at.t_wall_s - t_wall_s) * (self.vehicle.sim_rate() or 1.0)
        return min(max(age, 0.0), 5.0) if math.isfinite(age) else 0.0

    def _reaction(self, pose: PoseSample) -> Reaction:
        """Whom the planner reacts to (fleet.react_to: separation from all, sightline to one)."""
        return react_to(pose.x_east_m, pose.y_north_m, self.ctx.rank[self.name], self._neighbours(pose),
                        self.ctx.mission.hides_from(self.name))

    def _nearest_other(self, pose: PoseSample) -> tuple[str | None, OtherUav | None]:
        """The nearest other vehicle, from its own telemetry, extrapolated to this pose's time."""
        nearest = min(self._neighbours(pose), default=None,
                      key=lambda n: math.hypot(n.uav.x_m - pose.x_east_m, n.uav.y_m - pose.y_north_m))
        return (None, None) if nearest is None else (nearest.name, nearest.uav)

    def _neighbours(self, pose: PoseSample) -> list[Neighbour]:
        """Every other vehicle with telemetry, extrapolated to this pose's time."""
        out = []
        for name, v in self.ctx.vehicles.items():
            p = v.latest_pose() if name != self.name else None
            if p is None:
                continue
            age = self._age_s(pose, p.t_sim_s, p.t_wall_s, same_link=False)
            x, y = p.x_east_m + p.vx_east_m_s * age, p.y_north_m + p.vy_north_m_s * age
            out.append(Neighbour(name, self.ctx.rank[name],
                                 OtherUav(x, y, p.vx_east_m_s, p.vy_north_m_s, arrived=name in self.ctx.arrived)))
        return out

    def _traffic(self) -> dict[str, TrafficReport]:
        """Each moving obstacle's latest report, preferring this vehicle's own link."""
        merged: dict[str, TrafficReport] = {}
        for v in self.ctx.vehicles.values():
            for callsign, r in v.traffic().items():
                cur = merged.get(callsign)
                if cur is None or (cur.via != self.name and (r.via == self.name or r.t_wall_s > cur.t_wall_s)):
                    merged[callsign] = r
        return merged

    def _obstacle_tracks(self, pose: PoseSample) -> list[ObstacleTrack]:
        tracks = []
        for callsign, r in self._traffic().items():
            self.ctx.log.traffic(r.t_sim_s, callsign, r.via, r.x_east_m, r.y_north_m, r.vx_east_m_s, r.vy_north_m_s)
            age = self._age_s(pose, r.t_sim_s, r.t_wall_s, same_link=r.via == self.name)
            tracks.append(ObstacleTrack(self.ctx.obstacle_id(callsign), r.x_east_m + r.vx_east_m_s * age,
                                        r.y_north_m + r.vy_north_m_s * age, r.vx_east_m_s, r.vy_north_m_s))
        return tracks

    def _setpoint(self, pose: PoseSample, result: TickResult) -> tuple[VelocityYawRateSetpoint, str]:
        if result.command is None:
            reason = result.hold_reason or "no command"
            self.outcome.interventions[f"planner: {reason}"] += 1
            return HOVER, f"hover ({reason})"
        v, w = result.speed_m_s, result.yaw_rate_rad_s
        s = self.ctx.settings
        dt = self.ctx.mission.planner.dt_s
        own = monitors.Kinematic2D(pose.x_east_m, pose.y_north_m, pose.heading_enu_rad,
                                   pose.vx_east_m_s, pose.vy_north_m_s)
        other_name, other = self._nearest_other(pose)
        other_k = None if other is None else monitors.Kinematic2D(other.x_m, other.y_m, 0.0, other.vx_m_s, other.vy_m_s)
        priority = other_name is None or self.ctx.rank[self.name] < self.ctx.rank[other_name]
        stop_m = self._stop_distance_m(pose)
        for verdict in (
            monitors.check_separation(own, v, w, other_k, min_separation_m=self.ctx.mission.safety.min_separation_m,
                                      own_has_priority=priority,
                                      horizon_s=s.lookahead_s, step_s=dt / 2, stop_m=stop_m),
            monitors.check_geofence(self.ctx.mission.world, own, v, w, horizon_s=s.lookahead_s, step_s=dt / 2,
                                    stop_m=stop_m),
        ):
            if verdict.hover:
                self.outcome.interventions[verdict.reason] += 1
                if verdict.reason == "geofence":
                    return self._turn_in(pose, dt), "turn in place (geofence monitor)"
                return HOVER, f"hover ({verdict.reason} monitor)"
        # The planner is planar; hold the cruise altitude with a gentle proportional climb rate.
        climb = max(-1.0, min(1.0, 0.5 * (self.spec.cruise_alt_m - pose.alt_rel_m)))
        action = "fly"
        if result.recovery_reason is not None:  # speed 0 + yaw rate: the autopilot yaws in place
            self.outcome.interventions["planner: spin recovery"] += 1
            action = "recover (yaw in place)"
        return VelocityYawRateSetpoint(forward_m_s=v, yaw_rate_enu_rad_s=w, climb_m_s=climb), action

    def _stop_distance_m(self, pose: PoseSample) -> float:
        """What the vehicle flies after a veto: on the old command for the pose's age (on the
        vehicle's clock, or since it arrived at the measured speed factor) and a planner step,
        then braking. On a busy machine the age is a second of sim or more at 20x."""
        clock, rate = self.vehicle.clock_s(), self.vehicle.sim_rate() or 1.0
        age = max(0.0 if clock is None else clock - pose.t_sim_s, (time.monotonic() - pose.t_wall_s) * rate)
        age = min(max(age, 0.0), self.ctx.mission.safety.telemetry_timeout_s)
        return monitors.stop_distance_m(pose.ground_speed_m_s, self.spec.max_accel_m_s2,
                                        age + self.ctx.mission.planner.dt_s)

    def _turn_in(self, pose: PoseSample, dt: float) -> VelocityYawRateSetpoint:
        """Stop and yaw toward the middle of the area. The monitor looks closer than the planner
        (half its step), so near the fence it can veto a command the planner found legal; a plain
        hover keeps the heading, and the planner would ask for the same command for ever."""
        w = self.ctx.mission.world
        cx, cy = (w.x_min_m + w.x_max_m) / 2.0, (w.y_min_m + w.y_max_m) / 2.0
        error = frames.wrap_pi(math.atan2(cy - pose.y_north_m, cx - pose.x_east_m) - pose.heading_enu_rad)
        rate = self.spec.max_yaw_rate_rad_s
        return VelocityYawRateSetpoint(forward_m_s=0.0, yaw_rate_enu_rad_s=max(-rate, min(rate, error / dt)))

    # -- logging ----------------------------------------------------------------------------
    def _record(self, pose: PoseSample) -> None:
        if pose.plausible:  # a sample that jumped (another system's, on a shared id) is no path flown
            self.ctx.log.track(self.name).add(self.ctx.track_time(self, pose.t_sim_s), pose.x_east_m, pose.y_north_m)

    async def _record_until_landed(self) -> None:
        """Go on recording the track after the arrival, until the vehicle is on the ground: it
        brakes in HOLD (PX4's stopping distance, 15-50 m from cruise) and lands, and separation
        and clearance are judged where it flew, not where it crossed the arrival radius."""
        seq = -1
        while self.vehicle.status().landed is not LandedState.ON_GROUND:
            pose = self.vehicle.latest_pose()
            if pose is not None and pose.seq != seq:
                seq = pose.seq
                self._record(pose)
            try:
                await self.vehicle.wait_until(lambda st, p: p is not None and p.seq != seq, 1.0, "position")
            except TelemetryLost:
                continue  # the hold or the landing goes on; a dead link is the landing's to report

    def _remaining_m(self, pose: PoseSample) -> float:
        nodes = self.planner.tracker.nodes
        i = self.planner.tracker.index
        rest = float(np.sum(np.hypot(*np.diff(nodes[i:], axis=0).T))) if i < len(nodes) - 1 else 0.0
        return math.hypot(nodes[i][0] - pose.x_east_m, nodes[i][1] - pose.y_north_m) + rest

    def _log_tick(self, pose: PoseSample, t_mission: float, result: TickResult,
                  setpoint: VelocityYawRateSetpoint, action: str) -> None:
        clear_m = clearance_here_m(pose.x_east_m, pose.y_north_m, self._snapshot)
        _, other = self._nearest_other(pose)
        sep_m = math.inf if other is None else math.hypot(other.x_m - pose.x_east_m, other.y_m - pose.y_north_m)
        to_go = self._remaining_m(pose)
        mode = self.vehicle.status().mode.value
        self.ctx.log.row(t_mission_s=t_mission, t_sim_s=pose.t_sim_s, vehicle=self.name, phase=self.outcome.phase,
                         mode=mode, x_m=pose.x_east_m, y_m=pose.y_north_m, alt_m=pose.alt_rel_m,
                         heading_deg=math.degrees(pose.heading_enu_rad), speed_m_s=pose.ground_speed_m_s,
                         cmd_forward_m_s=setpoint.forward_m_s, cmd_yaw_rate_deg_s=math.degrees(setpoint.yaw_rate_enu_rad_s),
                         action=action, goal_index=result.goal_index, dist_to_goal_m=to_go, clearance_m=clear_m,
                         separation_m=sep_m, planner_ms=result.planner_ms, t_plan_s=self._t_plan)
        if t_mission >= self._next_progress_s:
            self._next_progress_s = t_mission + self.ctx.settings.progress_every_s
            self.ctx.report(f"t={t_mission:7.1f} s  {self.name:>3} {mode:<8} to go {to_go:7.0f} m  "
                            f"clear (inflated) {clear_m:6.0f} m  separation {sep_m:6.0f} m  {action}")
