"""One pilot's way into the air, as PX4 wants it. Mixed into :class:`companion.app.pilot.Pilot`.

    (LAND/RTL on the ground: HOLD first) -> arm, retried while PX4 refuses it during boot
    -> (all armed) -> arm again if COM_DISARM_PRFLT ran out (or nearly) meanwhile -> take off,
    confirm armed (disarmed on the ground before lifting: arm and take off once more)
    -> (airborne) ... setpoints streaming for a second, then OFFBOARD, asked again until the
    heartbeat shows it -> yaw in place to the mission's initial heading

PX4 refuses to arm for ~4.2 s after boot (TEMPORARILY_REJECTED, which MAVSDK reports as
COMMAND_DENIED), disarms 10 s after an arm without take-off, refuses to arm in LAND after a
landing on the stub, and spawns facing north: see ../shared/px4-sih/README.md.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import TYPE_CHECKING

from uav_model import frames
from companion.app.context import wall_for_sim
from companion.errors import CommandRefused, MissionAborted, TelemetryLost
from companion.vehicle.port import HOVER, FlightMode, LandedState, VelocityYawRateSetpoint

if TYPE_CHECKING:
    from uav_model.mission import VehicleSpec
    from companion.app.context import FlightContext, PilotOutcome
    from companion.vehicle.port import Vehicle

# Arm refusals worth another try: the autopilot may accept once its estimator has settled.
ARM_RETRY_RESULTS = frozenset({"COMMAND_DENIED", "TEMPORARILY_REJECTED", "BUSY", "TIMEOUT", "UNKNOWN"})
REARM_MODES = frozenset({FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH, FlightMode.TAKEOFF})
TAKEOFF_ATTEMPTS = 3  # a take-off the preflight disarm beat on the ground (a lost command) is tried again
ARM_CONFIRM_ATTEMPTS = 3  # arm commands whose heartbeat confirmation is awaited
ON_GROUND_ALT_M = 1.0  # disarmed below this: it never lifted, arming again is safe
PRFLT_MARGIN_SIM_S = 5.0  # take off at least this long before COM_DISARM_PRFLT runs out (PX4 detects take-off ~1.6 s after the command)
MIN_ALIGN_RATE_RAD_S = math.radians(30.0)  # PX4 yaws in place at 86-90 deg/s; the stub at v/r
# PX4 takes OFFBOARD only while its health checks see a live setpoint stream (its docs: streamed for
# over a second), acks DO_SET_MODE even when it then stays where it is, and shows the mode only in
# its 1 Hz heartbeat: stream first, ask, and ask again while the heartbeat does not show it.
OFFBOARD_LEAD_SIM_S = 1.0
OFFBOARD_ASK_EVERY_SIM_S = 2.0


class Departure:
    ctx: FlightContext
    spec: VehicleSpec
    name: str
    vehicle: Vehicle
    outcome: PilotOutcome
    setpoint: VelocityYawRateSetpoint
    _armed_at_sim_s: float | None = None  # the vehicle's clock when the last arm was confirmed

    def _climb_sim_s(self) -> float:
        return self.spec.cruise_alt_m / 0.5 + 30.0  # PX4 climbs at >= 0.5 m/s (MPC_TKO_SPEED)

    async def _take_off(self) -> None:
        self.outcome.phase = "arming"  # from here on the vehicle may be armed, even if we are cancelled
        await self._leave_landing_mode()
        prflt = await self.vehicle.get_param("COM_DISARM_PRFLT")  # read before arming: nothing between arm and take-off
        await self._arm()
        self.outcome.phase = "armed"
        # Nobody leaves the ground unless everybody could arm: a refusal then only disarms.
        await self._barrier("all vehicles armed", wall_for_sim(self.vehicle, self.ctx.settings.arm_retry_s, 30.0))
        await self._keep_armed_for_takeoff(prflt)
        alt = self.spec.cruise_alt_m
        for attempt in range(1, TAKEOFF_ATTEMPTS + 1):
            await self._retry("takeoff", lambda: self.vehicle.takeoff(alt))
            self.outcome.phase = "takeoff"
            target = alt - 1.0  # PX4 ends TAKEOFF within a few decimetres of MIS_TAKEOFF_ALT
            await self.vehicle.wait_until(lambda s, p: not s.armed or (p is not None and p.alt_rel_m >= target),
                                          wall_for_sim(self.vehicle, self._climb_sim_s()), f"take-off to {alt:g} m")
            if self.vehicle.status().armed:
                break
            pose = self.vehicle.latest_pose()
            if attempt == TAKEOFF_ATTEMPTS or pose is None or pose.alt_rel_m > ON_GROUND_ALT_M:
                raise MissionAborted("disarmed", "disarmed during take-off", vehicle=self.name)
            # Disarmed before it lifted (COM_DISARM_PRFLT raced the take-off command): arm, go again.
            self.ctx.report(f"{self.name}: disarmed on the ground before take-off; arming again")
            self.outcome.phase = "arming"
            await self._leave_landing_mode()  # PX4 may sit in TAKEOFF, disarmed: HOLD first
            await self._arm()
        self.outcome.phase = "airborne"
        self.ctx.report(f"{self.name}: airborne at {alt:g} m")

    async def _keep_armed_for_takeoff(self, prflt_s: float | None) -> None:
        """PX4 disarms COM_DISARM_PRFLT (sim) after an arm without take-off. If the wait for the
        others has used up most of it, disarm and arm again now, just before the take-off command,
        rather than let the autopilot disarm it in the middle of the take-off."""
        st = self.vehicle.status()
        now, armed_at = self.vehicle.clock_s(), self._armed_at_sim_s
        if st.armed and prflt_s is not None and prflt_s >= 0 and now is not None and armed_at is not None \
                and now - armed_at > prflt_s - PRFLT_MARGIN_SIM_S:
            self.ctx.report(f"{self.name}: armed {now - armed_at:.1f} s ago, COM_DISARM_PRFLT {prflt_s:g} s: "
                            "arming again just before take-off")
            await self._retry("disarm", self.vehicle.disarm)
            await self.vehicle.wait_until(lambda s, p: not s.armed, wall_for_sim(self.vehicle, 3.0), "disarmed")
        elif not st.armed:  # COM_DISARM_PRFLT ran out while the others armed (a clock we could not read)
            self.ctx.report(f"{self.name}: disarmed while waiting for the others (auto preflight disarm); arming again")
        else:
            return
        await self._arm()

    async def _leave_landing_mode(self) -> None:
        """After a landing the vehicle may sit in LAND (or RTL): switch to HOLD before arming."""
        st = self.vehicle.status()
        if st.mode in REARM_MODES and not st.armed and st.landed in (LandedState.ON_GROUND, LandedState.UNKNOWN):
            self.ctx.report(f"{self.name}: on the ground in {st.mode.value}; switching to HOLD to arm again")
            await self._retry("hold", lambda: self.vehicle.set_mode(FlightMode.HOLD, "hold"))
            await self.vehicle.wait_until(lambda s, p: s.mode is FlightMode.HOLD,
                                          wall_for_sim(self.vehicle, 5.0), "HOLD before arming")

    async def _arm(self) -> None:
        """Arm, retried with backoff while the refusal may pass (bounded in sim time); then
        confirm it from the heartbeat, as an ack alone does not prove it."""
        budget_wall = wall_for_sim(self.vehicle, self.ctx.settings.arm_retry_s, 1.0)
        give_up = time.monotonic() + budget_wall
        delay_sim = 0.25
        while True:
            self.outcome.arm_attempts += 1
            try:
                await self.vehicle.arm()
                break
            except CommandRefused as exc:
                wait_wall = wall_for_sim(self.vehicle, delay_sim, 0.0)
                if exc.result not in ARM_RETRY_RESULTS or time.monotonic() + wait_wall > give_up:
                    raise
                if self.outcome.arm_attempts == 1:
                    self.ctx.report(f"{self.name}: arm refused ({exc.result}); retrying for up to "
                                    f"{self.ctx.settings.arm_retry_s:g} s")
                await asyncio.sleep(wait_wall)
                delay_sim = min(2.0 * delay_sim, 2.0)
        for confirm in range(1, ARM_CONFIRM_ATTEMPTS + 1):
            try:
                await self.vehicle.wait_until(lambda s, p: s.armed, wall_for_sim(self.vehicle, 3.0), "armed")
                break
            except TelemetryLost:
                # Armed while the link was down, then disarmed by COM_DISARM_PRFLT before it came
                # back: the heartbeats say disarmed ever since. Arm again, a bounded number of times.
                if confirm == ARM_CONFIRM_ATTEMPTS or self.vehicle.status().armed:
                    raise
                self.ctx.report(f"{self.name}: armed was never confirmed; arming again")
                self.outcome.arm_attempts += 1
                await self.vehicle.arm()
        self._armed_at_sim_s = self.vehicle.clock_s()
        if self.outcome.arm_attempts > 1:
            self.ctx.report(f"{self.name}: armed after {self.outcome.arm_attempts} attempts")

    async def _enter_offboard(self) -> None:
        """OFFBOARD, from a hover whose setpoints the keep-alive streams from before this call."""
        await self.vehicle.send_setpoint(self.setpoint)
        pose = self.vehicle.latest_pose()
        if pose is not None:
            lead_until = pose.t_sim_s + OFFBOARD_LEAD_SIM_S
            try:
                await self.vehicle.wait_until(lambda s, p: p is not None and p.t_sim_s >= lead_until,
                                              wall_for_sim(self.vehicle, OFFBOARD_LEAD_SIM_S, 1.0),
                                              "setpoints streaming")
            except TelemetryLost:
                pass  # the requests below tell whether the autopilot takes it
        total_wall = wall_for_sim(self.vehicle, self.ctx.settings.offboard_entry_s)
        give_up = time.monotonic() + total_wall
        requests = 0
        while True:
            requests += 1
            await self._retry("offboard start", lambda: self.vehicle.start_offboard(self.setpoint))
            each_wall = min(wall_for_sim(self.vehicle, OFFBOARD_ASK_EVERY_SIM_S, 0.5),
                            max(0.1, give_up - time.monotonic()))
            try:
                await self.vehicle.wait_until(lambda s, p: s.mode is FlightMode.OFFBOARD, each_wall, "OFFBOARD mode")
                break
            except TelemetryLost:
                if time.monotonic() >= give_up:
                    raise CommandRefused("offboard start", "MODE_UNCHANGED", vehicle=self.name, detail=(
                        f"still {self.vehicle.status().mode.value} after {requests} requests in "
                        f"{total_wall:.1f} s wall")) from None
        if requests > 1:
            self.ctx.report(f"{self.name}: OFFBOARD after {requests} requests")

    async def _align_heading(self) -> None:
        """Yaw in place (in OFFBOARD, hovering) to the mission's initial heading: PX4 spawns facing
        north, and the planner assumes the mission's heading at departure."""
        tol = math.radians(self.ctx.settings.yaw_align_tolerance_deg)
        goal = self.spec.initial_heading_rad
        rate_max = max(self.spec.max_yaw_rate_rad_s, MIN_ALIGN_RATE_RAD_S)
        pose = self.vehicle.latest_pose()
        assert pose is not None
        error = frames.wrap_pi(goal - pose.heading_enu_rad)
        if abs(error) <= tol:
            return
        self.ctx.report(f"{self.name}: yawing {math.degrees(error):+.0f} deg to the mission heading "
                        f"{self.spec.initial_heading_deg:g} deg before departure")
        bound_wall = wall_for_sim(self.vehicle, abs(error) / rate_max + 20.0)
        deadline = time.monotonic() + bound_wall
        seq = pose.seq
        try:
            while abs(error) > tol / 2:
                rate = max(-rate_max, min(rate_max, 1.5 * error))
                self.setpoint = VelocityYawRateSetpoint(0.0, rate, 0.0)
                await self.vehicle.send_setpoint(self.setpoint)
                pose = await self.vehicle.next_pose(seq, max(0.1, deadline - time.monotonic()))
                seq = pose.seq
                error = frames.wrap_pi(goal - pose.heading_enu_rad)
        except TelemetryLost:
            raise MissionAborted("timeout", f"could not yaw to {self.spec.initial_heading_deg:g} deg "
                                 f"within {bound_wall:.0f} s wall", vehicle=self.name) from None
        finally:
            self.setpoint = HOVER
