"""ORCA (RVO2, through ``pyrvo``) as an external baseline variant of ``companion bench``.

ORCA (van den Berg et al. 2011) is the usual reciprocal collision-avoidance baseline. Here each
vehicle is an ORCA agent whose preferred velocity points along its A* route (the same sparse
nodes astar-bdwa tracks, the same local-goal tracker) at cruise speed; the static obstacles are
ORCA polygons (their inflated footprints, as the planner sees them); moving obstacles are agents
placed at their true position and velocity every tick (ORCA assumes they reciprocate, which they
do not: a known weakness of the baseline, kept, not hidden). ORCA's new velocity is flown as a
LOCAL_NED velocity setpoint through the mission's plant, and the flight is scored by the same
:func:`companion.planning.metrics.summarize` as the four variants, so rows are comparable.

The baseline is not a mission variant: ``companion simulate`` cannot replay it (its failure
folder's scenario.yaml replays the scenario with astar-bdwa).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from companion.planning.local_goals import LocalGoalTracker
from companion.planning.metrics import TruthGeometry, summarize
from companion.planning.routes import Route, plan_routes
from companion.planning.flight.loop import RunResult, SafetyWatch, start_states, tracks_from_rows
from uav_model.frames import enu_to_ned, ned_to_enu
from uav_model.mission import Mission
from uav_model.plant import HOVER, VelocityCommand, VelocityFrame, step_for

ORCA = "orca"
BASELINES = (ORCA,)
ROUTE_VARIANT = "astar-bdwa"  # the replay a failure folder writes, and whose routes ORCA follows


@dataclass(frozen=True)
class OrcaSettings:
    """RVO2's agent parameters, in metres and seconds."""

    neighbour_dist_m: float = 600.0
    max_neighbours: int = 10
    time_horizon_s: float = 20.0  # other agents
    time_horizon_obstacle_s: float = 10.0
    radius_margin_m: float = 5.0  # on top of half the separation
    circle_sides: int = 24  # a circle becomes the polygon circumscribing it


MISSING_PYRVO = "the orca baseline needs pyrvo (the orca extra): pip install -e '.[orca]'"


def pyrvo_missing() -> str | None:
    """The one-line refusal when ``orca`` is asked for without pyrvo installed, else None."""
    import importlib.util
    return MISSING_PYRVO if importlib.util.find_spec("pyrvo") is None else None


def _import_pyrvo():
    try:
        import pyrvo
    except ImportError:  # the optional extra
        raise RuntimeError(MISSING_PYRVO) from None
    return pyrvo


def _polygon(obstacle, sides: int) -> list[tuple[float, float]]:
    """The obstacle's inflated footprint as a counter-clockwise vertex list (RVO2's convention)."""
    if obstacle.is_circle:
        r = obstacle.inflated_radius_m / math.cos(math.pi / sides)  # circumscribed: never smaller
        cx, cy = obstacle.center
        a = 2.0 * math.pi * np.arange(sides) / sides
        return [(float(cx + r * math.cos(t)), float(cy + r * math.sin(t))) for t in a]
    ring = obstacle.inflated.exterior
    coords = list(ring.coords)[:-1]
    if not ring.is_ccw:
        coords.reverse()
    return [(float(x), float(y)) for x, y in coords]


def simulate_orca(mission: Mission, *, routes: dict[str, Route] | None = None,
                  lower_bounds_s: dict[str, float | None] | None = None,
                  settings: OrcaSettings = OrcaSettings()) -> RunResult:
    """Fly ``mission`` with ORCA steering every vehicle along its A* route; score it."""
    pyrvo = _import_pyrvo()
    started = time.perf_counter()
    mission = mission.with_variant(ROUTE_VARIANT)
    routes = routes if routes else plan_routes(mission)
    vehicles = mission.by_priority
    names = [v.name for v in vehicles]
    dt = mission.planner.dt_s
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(dt)
    radius = mission.safety.min_separation_m / 2.0 + settings.radius_margin_m
    sim.set_agent_defaults(settings.neighbour_dist_m, settings.max_neighbours, settings.time_horizon_s,
                           settings.time_horizon_obstacle_s, radius, 10.0, [0.0, 0.0])
    moving = []
    for o in mission.world.obstacles:
        if o.is_moving:
            moving.append(o)
        else:
            sim.add_obstacle(_polygon(o, settings.circle_sides))
    sim.process_obstacles()
    limits, states = start_states(mission)
    agent = {}
    for v in vehicles:
        agent[v.name] = sim.add_agent(list(v.start_enu_m))
        sim.set_agent_max_speed(agent[v.name], v.speed_m_s)
    movers = [sim.add_agent(list(o.center)) for o in moving]
    for o, k in zip(moving, movers):
        sim.set_agent_radius(k, o.inflated_radius_m)
        sim.set_agent_max_speed(k, 1e3)
    trackers = {v.name: LocalGoalTracker(routes[v.name].sparse_enu_m, mission.planner.acceptance_radius_m)
                for v in vehicles}
    step = step_for(mission.plant)
    truth = TruthGeometry(mission.world)
    radius_arrive = mission.safety.arrival_radius_m
    rows = [[_xy(states[n]) for n in names]]
    last_row: dict[str, int | None] = {n: None for n in names}
    active = list(names)
    watch, bad = SafetyWatch(mission, truth, dt), None
    for k in range(int(math.floor(mission.safety.time_limit_s / dt + 1e-9))):
        t = k * dt
        for o, a in zip(moving, movers):
            off = o.offset_at(np.array([t]))[0]
            sim.set_agent_position(a, [float(o.center[0] + off[0]), float(o.center[1] + off[1])])
            vx, vy = o.motion.velocity_at(t)
            sim.set_agent_velocity(a, [float(vx), float(vy)])
            sim.set_agent_pref_velocity(a, [float(vx), float(vy)])
        for v in vehicles:
            x, y = _xy(states[v.name])
            vx, vy, _ = ned_to_enu(states[v.name].vn_m_s, states[v.name].ve_m_s)
            sim.set_agent_position(agent[v.name], [x, y])
            sim.set_agent_velocity(agent[v.name], [vx, vy])
            pref = (0.0, 0.0)
            if v.name in active:
                tracker = trackers[v.name]
                gx, gy = tracker.update(x, y)
                d = math.hypot(gx - x, gy - y)
                if math.hypot(*(np.subtract(v.goal_enu_m, (x, y)))) <= radius_arrive:
                    active.remove(v.name)
                    last_row[v.name] = k
                elif d > 1e-6:
                    pref = (v.speed_m_s * (gx - x) / d, v.speed_m_s * (gy - y) / d)
            sim.set_agent_pref_velocity(agent[v.name], list(pref))
        if not active:
            break
        sim.do_step()
        for name in active:
            vx, vy = sim.get_agent_velocity(agent[name]).to_tuple()
            vn, ve, _ = enu_to_ned(vx, vy)
            command = VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, 0.0, 0.0) if math.isfinite(vx + vy) else HOVER
            states[name] = step(states[name], command, limits[name], dt)
        rows.append([_xy(states[n]) for n in names])
        bad = watch.poll(rows, force=k == 0)
        if bad is not None:
            break
    if bad is None:
        bad = watch.finish(rows)
    if bad is not None:
        del rows[bad + 2:]
    tracks = tracks_from_rows(names, rows, last_row, dt)
    summary = summarize(mission, tracks, routes=routes, geometry=truth, lower_bounds_s=lower_bounds_s)
    return RunResult(mission, ORCA, dict(routes), tracks, {n: [] for n in names}, summary,
                     time.perf_counter() - started)


def _xy(state) -> tuple[float, float]:
    x, y, _ = ned_to_enu(state.north_m, state.east_m)
    return x, y
