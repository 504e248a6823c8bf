"""Before anything arms: read each vehicle, run the pre-flight checks, decide the clock.

    facts = await read_facts(vehicle)                       (pose, heading, home, GPS, battery, params)
    ready = await get_ready(plan, vehicles, settings, ...)  -> Readiness (the plan to fly, shared clock)

The checks themselves are pure (:mod:`companion.app.preflight`); this module does their I/O and
raises :class:`~companion.errors.PreflightRefused` with the first refusal's line (CLI exit 2).
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from companion.app.context import RunSettings
from companion.app.flight_plan import FlightPlan, prepare
from companion.app.offload import in_child_process
from companion.app.preflight import (LIMIT_PARAMS, OBL_ACTIONS, OBL_HOLD, PreflightReport, PreflightSettings, Severity,
                                     VehicleFacts, preflight)
from companion.errors import PreflightRefused
from companion.planning.errors import PlanningError
from companion.planning.routes import Route
from companion.planning.variants import VARIANTS
from uav_model.mission import Mission, MissionError
from companion.vehicle.port import LandedState, Vehicle

SHARED_CLOCK_TOLERANCE_S = 0.5  # sim: two clocks this close are one (an external sim-bridge) ...
CLOCK_JITTER_WALL_S = 0.05  # ... or closer than what 50 ms of delivery jitter makes of them at the speed factor
CLOCK_SAMPLES = 8


@dataclass(frozen=True)
class Readiness:
    plan: FlightPlan  # what to fly: derated to the autopilots' limits, or re-planned from where they are
    shared_clock: bool
    report: PreflightReport


async def read_facts(vehicle: Vehicle) -> VehicleFacts:
    """What the checks need from one vehicle; parameters it does not have read as None."""
    values = [await vehicle.get_param(n) for n in LIMIT_PARAMS]
    pose, st = vehicle.latest_pose(), vehicle.status()
    return VehicleFacts(
        name=vehicle.name, x_east_m=None if pose is None else pose.x_east_m,
        y_north_m=None if pose is None else pose.y_north_m,
        heading_enu_rad=None if pose is None else pose.heading_enu_rad, armed=st.armed,
        in_air=st.landed in (LandedState.IN_AIR, LandedState.LANDING, LandedState.TAKING_OFF),
        home_ok=st.home_ok, gps_fix_type=st.gps_fix_type, battery_pct=st.battery_pct,
        params=dict(zip(LIMIT_PARAMS, values)), link_anomaly=st.link_anomaly)


def plan_for_flight(mission: Mission, variant: str, routes: Mapping[str, Route] | None, geofence: bool) -> FlightPlan:
    """The plan to fly ``mission``: its routes (planned again when None) and its space-time plan
    worked out (the child process's job)."""
    plan = prepare(mission, variant) if routes is None else FlightPlan(mission, variant, dict(routes))
    plan = dataclasses.replace(plan, geofence=geofence)
    _ = plan.coordinated
    return plan


def route_length_m(plan: FlightPlan, name: str) -> float:
    nodes = plan.nodes_enu_m(plan.mission.vehicle(name))
    return float(np.sum(np.hypot(*np.diff(nodes, axis=0).T))) if len(nodes) > 1 else 0.0


# Autopilots booted within a fraction of a second of each other (PX4 SITL instances a script starts
# together) stamp clocks the detection cannot tell from one: it says so when it finds one clock.
SAME_CLOCK_HINT = ("; separate autopilots booted together look the same: give --no-shared-clock if each "
                   "vehicle has its own (--sim px4 knows it does)")


async def detect_shared_clock(vehicles: Mapping[str, Vehicle]) -> bool:
    """True when every vehicle stamps with one sim clock (an external sim-bridge runs them all),
    False for independent autopilots (PX4 instances boot at different times). Each clock is
    projected to one wall instant with its measured rate; agreement within the tolerance
    (:func:`clocks_agree`) is one clock."""
    if len(vehicles) < 2:
        return True
    spreads, rates = [], []
    for _ in range(CLOCK_SAMPLES):
        await asyncio.sleep(0.05)
        now = time.monotonic()
        projected = []
        for v in vehicles.values():
            t, rate = v.clock_s(), v.sim_rate()
            wall = getattr(getattr(v, "board", None), "latest_clock_wall_s", None)
            if t is None:
                return False
            if wall is not None and rate is not None:
                t += (now - wall) * rate
                rates.append(rate)
            projected.append(t)
        spreads.append(max(projected) - min(projected))
    return clocks_agree(spreads, max(rates, default=None))


def clocks_agree(spreads_s: list[float], sim_rate: float | None) -> bool:
    """Whether clock spreads (sim seconds, one per sample) say one clock.

    A sample's spread is the clocks' true offset plus delivery jitter: a busy machine delivers a
    vehicle's stamp tens of ms late, which at 20x is a second of sim. The smallest spread is the
    best estimate of the offset, and the tolerance grows with the speed factor; treating two
    independent clocks closer than that as one costs at most that much sim time.
    """
    tolerance = max(SHARED_CLOCK_TOLERANCE_S, CLOCK_JITTER_WALL_S * (sim_rate or 0.0))
    return min(spreads_s) <= tolerance


async def get_ready(plan: FlightPlan, vehicles: Mapping[str, Vehicle], settings: RunSettings,
                    checks: PreflightSettings, report: Callable[[str], None]) -> Readiness:
    """Wait for every vehicle's health and position, check them, and decide what to fly."""
    await asyncio.gather(*(v.wait_ready(settings.ready_timeout_s) for v in vehicles.values()))
    inline = all(getattr(v, "clock_follows_event_loop", False) for v in vehicles.values())
    facts = dict(zip(vehicles, await asyncio.gather(*(read_facts(v) for v in vehicles.values()))))
    routes = {n: route_length_m(plan, n) for n in vehicles}
    result = preflight(plan.mission, facts, routes, settings.keepalive_sim_s, checks)
    for f in result.findings:
        if f.severity is not Severity.INFO or f.check.value in ("station", "heading", "turn", "offboard loss", "battery"):
            report(f"pre-flight {f.severity.name.lower()}: {f.line()}")
    if result.refusals:
        first = result.refusals[0]
        more = f" (and {len(result.refusals) - 1} more refusal(s) above)" if len(result.refusals) > 1 else ""
        raise PreflightRefused(f"pre-flight: {first.message}{more}", vehicle=first.vehicle)
    unchanged = all(a is b for a, b in zip(result.mission.vehicles, plan.mission.vehicles))
    if unchanged:
        flown = plan  # nothing derated: keep the plan, and the space-time plan computed before the flight
    elif result.replan or VARIANTS[plan.variant].timed and plan.routes:
        # Re-stationed, or derated with a schedule: routes or schedule change with the starts and
        # speeds. Seconds of pure work (a minute on a loaded machine) with the links live: in a child
        # process, so telemetry keeps flowing; inline only where the sim clock follows this loop.
        job = (result.mission, plan.variant, None if result.replan else plan.routes, plan.geofence)
        report("planning again for the flown mission" + ("" if inline else " (in a child process)"))
        try:
            flown = plan_for_flight(*job) if inline else await in_child_process(plan_for_flight, *job)
        except (MissionError, PlanningError) as exc:  # e.g. no route from where a vehicle is
            raise PreflightRefused(f"pre-flight: planning the flown mission: {exc}") from None
        if flown.coordinated is not None:
            report(f"schedule re-planned for the flown mission: departure hold {flown.coordinated.hold_s:.1f} s")
    else:
        flown = FlightPlan(result.mission, plan.variant, plan.routes, geofence=plan.geofence)
    shared = settings.shared_clock if settings.shared_clock is not None else await detect_shared_clock(vehicles)
    report(f"clock: {'one sim clock for all vehicles' if shared else 'one clock per vehicle'}"
           + (" (detected)" if settings.shared_clock is None else "")
           + (SAME_CLOCK_HINT if shared and settings.shared_clock is None and len(vehicles) > 1 else ""))
    for spec in flown.mission.vehicles:  # take-off altitude before arming: nothing may stand between arm and take-off
        v = vehicles[spec.name]
        action = facts[spec.name].params.get("COM_OBL_RC_ACT")
        if settings.failsafe_hold and action is not None and int(action) != OBL_HOLD:
            await v.set_param("COM_OBL_RC_ACT", float(OBL_HOLD))
            was = f"{int(action)} ({OBL_ACTIONS.get(int(action), '?')})"
            report(f"{spec.name}: COM_OBL_RC_ACT {was} -> {OBL_HOLD} (Hold): "
                   "an offboard loss then holds in place instead of returning home across the obstacles")
        if await v.get_param("MIS_TAKEOFF_ALT") is not None:
            await v.set_param("MIS_TAKEOFF_ALT", float(spec.cruise_alt_m))
    return Readiness(flown, shared, result)
