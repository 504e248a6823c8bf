"""The live companion reads the timed routes as the headless runner does: the same planners
(``FlightPlan.fleet_setup`` is ``fleet_setup.build_fleet``, sight_near_m included) and the per-priority
clocks (``timed.PriorityClocks``), fed with each vehicle's own telemetry samples.

The pilots here are the real ones on real vehicle boards (the adapters' telemetry store); only the
link is missing: samples are put on the boards as an adapter would.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest

from companion.app.context import FlightContext, RunSettings
from companion.app.flight_log import FlightLog
from companion.app.flight_plan import prepare
from companion.app.pilot import Pilot
from companion.planning.coordination.clocks import sight_near_m
from companion.vehicle.board import BoardReaders, VehicleBoard
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
DEPARTURE_SIM_S = 100.0  # the common departure on the shared sim clock


class BoardVehicle(BoardReaders):
    """The Vehicle port's readers on a real board (what every adapter answers them from)."""

    def __init__(self, name: str):
        self._board = VehicleBoard(name)


@pytest.fixture(scope="module")
def plan():
    plan = prepare(load_mission(ROOT / "missions" / "small_reference.yaml"), "astar-bdwa-timed")
    assert plan.coordinated is not None and plan.coordinated.hold_s == 0.0  # a departs at t = 0
    return plan


def _flight(plan, shared_clock: bool = True):
    vehicles = {v.name: BoardVehicle(v.name) for v in plan.mission.vehicles}
    ctx = FlightContext(plan, RunSettings(), FlightLog(None), vehicles, report=lambda _: None,
                        shared_clock=shared_clock)
    ctx.departure_sim_s = DEPARTURE_SIM_S
    pilots = {spec.name: Pilot(ctx, spec) for spec in plan.mission.by_priority}
    for p in pilots.values():
        p.outcome.t_depart_sim_s = DEPARTURE_SIM_S
    return ctx, pilots, vehicles


def _at(vehicle: BoardVehicle, xy, t_mission_s: float):
    return asyncio.run(_put(vehicle, xy, t_mission_s))


async def _put(vehicle: BoardVehicle, xy, t_mission_s: float):
    return await vehicle.board.put_pose(
        t_sim_s=DEPARTURE_SIM_S + t_mission_s, x_east_m=float(xy[0]), y_north_m=float(xy[1]), alt_rel_m=20.0,
        vx_east_m_s=0.0, vy_north_m_s=0.0, heading_enu_rad=math.pi / 4)


def test_the_live_planners_are_the_headless_ones(plan):
    ctx, pilots, _ = _flight(plan)
    timed = plan.coordinated.timed
    b = pilots["b"].planner
    assert b is ctx.setup.planners["b"] and ctx.setup.clocks is not None
    assert b.timed_route is timed["b"]
    assert b.sight_near_m is not None and b.sight_near_m == pytest.approx(sight_near_m(plan.mission, timed, "b"))
    assert pilots["a"].planner.sight_near_m is None  # the first in priority carries no sightline term
    # What each plan keeps, as headless knows it: an in-flight re-plan must keep it at least as well.
    assert ctx.setup.clocks.blocking == plan.coordinated.blocking and plan.coordinated.blocking


def test_b_reads_its_plan_at_a_clock_held_back_by_a_lagging_a(plan):
    ctx, pilots, vehicles = _flight(plan)
    a_start = plan.mission.vehicle("a").start_enu_m
    route_b = plan.coordinated.timed["b"]
    # 30 s after the common departure, a is still at its station (its plan has it ~300 m on);
    # b is where its own plan has it.
    t = 30.0
    pose_a = _at(vehicles["a"], a_start, t)
    pose_b = _at(vehicles["b"], route_b.planned_position_at(t), t)
    pilots["b"]._tick(pose_b)
    pilots["a"]._tick(pose_a)
    # a waits for nobody (the paper's rule): its plan is read at sim time since the departure ...
    assert pilots["a"]._t_plan == pytest.approx(t)
    # ... b's at a clock over a only, held back to where a's position is on a's plan (+ 2 s slack):
    # one common clock would read b's plan at 30 s, where b is.
    assert pilots["b"]._t_plan < 5.0, pilots["b"]._t_plan
    assert ctx.worst_lag_s > 25.0

    # a's newer sample reaches b's clock at a's own sample time, whoever ticks next.
    a_on_plan = plan.coordinated.timed["a"].planned_position_at(20.0)
    _at(vehicles["a"], a_on_plan, t + 0.3)
    pilots["b"]._tick(_at(vehicles["b"], route_b.planned_position_at(t), t + 0.5))
    assert 20.0 < pilots["b"]._t_plan < 24.0, pilots["b"]._t_plan


@pytest.mark.parametrize("how", ["arrived", "failed"])
def test_a_vehicle_that_stops_flying_its_plan_frees_the_clocks(plan, how):
    ctx, pilots, vehicles = _flight(plan)
    a_start = plan.mission.vehicle("a").start_enu_m
    route_b = plan.coordinated.timed["b"]
    _at(vehicles["a"], a_start, 30.0)
    pilots["b"]._tick(_at(vehicles["b"], route_b.planned_position_at(30.0), 30.0))
    assert pilots["b"]._t_plan < 5.0
    (ctx.arrived if how == "arrived" else ctx.off_schedule).add("a")
    pilots["b"]._tick(_at(vehicles["b"], route_b.planned_position_at(30.0), 31.0))
    assert pilots["b"]._t_plan == pytest.approx(31.0)  # as headless: done() once a is no longer flying


def test_unrelated_clocks_count_from_each_vehicles_own_departure(plan):
    _, pilots, vehicles = _flight(plan, shared_clock=False)
    _at(vehicles["a"], plan.mission.vehicle("a").start_enu_m, 30.0)
    pilots["b"]._tick(_at(vehicles["b"], plan.coordinated.timed["b"].planned_position_at(30.0), 30.0))
    assert pilots["b"]._t_plan == pytest.approx(30.0)


def test_a_silent_vehicle_holds_the_clocks_back_at_most_their_limit(plan):
    ctx, pilots, vehicles = _flight(plan)
    _at(vehicles["a"], plan.mission.vehicle("a").start_enu_m, 30.0)  # a's last sample: nothing after it
    route_b = plan.coordinated.timed["b"]
    pilots["b"]._tick(_at(vehicles["b"], route_b.planned_position_at(30.0), 30.0))
    assert pilots["b"]._t_plan < 5.0
    pilots["b"]._tick(_at(vehicles["b"], route_b.planned_position_at(30.0), 200.0))
    # not frozen: at most ScheduleClock's max_lag_s (120 s) behind sim time, as headless
    assert 200.0 - 120.0 - 1e-6 <= pilots["b"]._t_plan < 200.0


async def _lagging_b(plan, vehicles, t: float = 30.0):
    """a on its plan at ``t``; b still at its station, ~300 m behind its own plan, before the
    planned closest approach (49.5 s): over the re-plan rule's lag (100 m)."""
    await _put(vehicles["a"], plan.coordinated.timed["a"].planned_position_at(t), t)
    return await _put(vehicles["b"], plan.mission.vehicle("b").start_enu_m, t)


async def _turns_until_done(ctx) -> int:
    """Turns of the event loop while the re-plan is in flight (0: it never left the loop)."""
    turns = 0
    while ctx.replan_task is not None:
        turns += 1
        await asyncio.sleep(0.001)
    return turns


def test_a_lagging_lower_vehicle_is_replanned_in_flight_beside_the_loop(plan):
    ctx, pilots, vehicles = _flight(plan)
    old = pilots["b"].planner.timed_route

    async def fly() -> int:
        pilots["b"]._tick(await _lagging_b(plan, vehicles))
        assert ctx.replan_task is not None  # the tick returned with the re-plan still running
        counted = asyncio.create_task(_turns_until_done(ctx))  # from now: the next tick's await counts too
        pilots["b"]._tick(await _put(vehicles["b"], plan.mission.vehicle("b").start_enu_m, 30.2))
        return await counted

    turns = asyncio.run(fly())
    assert turns >= 1, turns  # the loop kept turning while the thread planned (how often: the CPU's speed)
    new = pilots["b"].planner.timed_route
    assert new is not old and new is ctx.clocks.routes["b"]
    assert new.t_s[0] == pytest.approx(30.0)  # from where b was, at the time it was there
    assert new.xy_enu_m[0] == pytest.approx(plan.mission.vehicle("b").start_enu_m[:2], abs=1e-6)
    assert ctx.clocks.replans == {"a": 0, "b": 1} and ctx.clocks.tries["b"] == 1  # one in flight at a time
    assert ctx.replan_errors == 0


@pytest.mark.parametrize("how", ["stood down", "raised"])
def test_a_late_or_failed_replan_leaves_the_old_plan_flying(plan, how, monkeypatch):
    ctx, pilots, vehicles = _flight(plan)
    old = pilots["b"].planner.timed_route
    if how == "raised":
        def broken(job):
            raise RuntimeError("planner bug")
        monkeypatch.setattr(ctx.clocks, "plan", broken)

    async def fly() -> int:
        pilots["b"]._tick(await _lagging_b(plan, vehicles))
        assert ctx.replan_task is not None
        if how == "stood down":
            ctx.off_schedule.add("b")  # no longer flying its plan when the result comes back
        return await _turns_until_done(ctx)

    asyncio.run(fly())
    assert pilots["b"].planner.timed_route is old and ctx.clocks.routes["b"] is old
    assert ctx.clocks.replans["b"] == 0
    assert ctx.replan_errors == (1 if how == "raised" else 0)


def test_no_replan_from_a_stale_position_until_the_vehicle_reports_again(plan):
    # b's position stream stopped 5 s ago (a telemetry freeze; the pilot hovers it) while a flies
    # on: a's ticks must not re-plan b from where it was last seen. b's next sample starts it.
    ctx, pilots, vehicles = _flight(plan)
    b0 = plan.mission.vehicle("b").start_enu_m

    async def fly() -> None:
        await _put(vehicles["b"], b0, 25.0)
        pilots["a"]._tick(await _put(vehicles["a"], plan.coordinated.timed["a"].planned_position_at(30.0), 30.0))
        assert ctx.replan_task is None and ctx.clocks.tries["b"] == 0
        pilots["b"]._tick(await _put(vehicles["b"], b0, 30.2))
        assert ctx.replan_task is not None
        await _turns_until_done(ctx)

    asyncio.run(fly())
    assert ctx.clocks.replans["b"] == 1 and ctx.clocks.tries["b"] == 1
    assert ctx.clocks.routes["b"].t_s[0] == pytest.approx(30.2)
