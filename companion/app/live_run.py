"""The mission runner: connect every vehicle, fly them all with one task group, score the flight.

    run_mission(plan, connections, settings, out_dir, report, stop) -> RunResult
    save_run(out_dir, plan, result, problems)  -> SaveReport   (summary.json, then trajectory.png)

One Mavsdk connection per vehicle (opened in mission order, closed in reverse), one
:class:`~companion.app.pilot.Pilot` task per vehicle inside the mission's task group, and one
watcher task that turns an operator's stop request (Ctrl-C, SIGTERM) into ``interrupted``. Any
pilot's failure cancels the others; every pilot leaves its vehicle safe on the way out. The flown
tracks are scored by the shared metrics module, exactly as ``companion simulate`` scores its own.
The flight logs (flight.csv, traffic.csv) are written into ``out_dir`` as the flight goes; the
summary and the picture are written by :func:`save_run` once the caller has shown the verdict.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from contextlib import AbstractAsyncContextManager, AsyncExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.app.failsafe import FailsafeCause
from companion.app.flight_log import FlightLog
from companion.app.flight_plan import FlightPlan
from companion.app.pilot import FlightContext, Pilot, PilotOutcome, RunSettings
from companion.app.preflight import PreflightSettings
from companion.app.readiness import get_ready
from companion.app.results import SaveReport, save_results
from companion.app.run_record import LinkRecord, LiveSchedule
from companion.app.warmup import warm_up_planners
from companion.errors import (CommandRefused, CompanionError, LinkError, MissionAborted, MissionUploadError,
                              PreflightRefused, VehicleNotReady, primary_error)
from uav_model.mission import VehicleSpec
from companion.planning.coordination.certificate import certificates_doc
from companion.planning.metrics import RunSummary, Track, summarize, until_last_arrival
from companion.vehicle.mavsdk_open import open_mavsdk_vehicle
from companion.vehicle.port import Vehicle

# Opens one vehicle of the mission given its connection label; the default is MAVSDK on that URL.
VehicleOpener = Callable[[VehicleSpec, str], AbstractAsyncContextManager[Vehicle]]


@dataclass(frozen=True)
class RunResult:
    summary: RunSummary | None  # None when no vehicle got as far as departing
    summary_dict: dict[str, Any]
    outcomes: dict[str, PilotOutcome]
    reason: str | None  # None on success
    message: str | None
    wall_s: float
    tracks: dict[str, Track] = dataclasses.field(default_factory=dict)  # as flown, for the picture
    log_problems: tuple[str, ...] = ()  # flight logs that are not complete on disk

    @property
    def success(self) -> bool:
        return self.reason is None and self.summary is not None and self.summary.success


async def _watch_stop(stop: asyncio.Event) -> None:
    await stop.wait()
    raise MissionAborted("interrupted", "stopped by the operator (signal)")


async def run_mission(plan: FlightPlan, connections: Mapping[str, str], settings: RunSettings,
                      out_dir: Path | None, report: Callable[[str], None],
                      stop: asyncio.Event | None = None, link: LinkRecord | None = None,
                      open_vehicle: VehicleOpener | None = None,
                      checks: PreflightSettings = PreflightSettings()) -> RunResult:
    """Fly ``plan`` over the given MAVSDK connection URLs (vehicle name -> URL), or through
    ``open_vehicle`` (e.g. the in-process fleet's) when given. The pre-flight checks run before
    anything arms; a refusal is raised (PreflightRefused), not returned."""
    mission = plan.mission
    stop = stop or asyncio.Event()
    started = time.monotonic()
    outcomes: dict[str, PilotOutcome] = {}
    reason: str | None = None
    message: str | None = None
    shared_clock = False
    flight: FlightContext | None = None  # read after the flight: how far the schedule fell behind
    vehicles: dict[str, Vehicle] = {}  # read after the flight too: what each link guard kept out
    with FlightLog(out_dir) as log:
        try:
            async with AsyncExitStack() as stack:
                # Before connecting: the first tick's kernel loading would otherwise stall the loop in flight.
                log_warm = warm_up_planners(plan)
                report(f"planner warmed up in {log_warm:.1f} s")
                for spec in mission.vehicles:
                    url = connections[spec.name]
                    opened = (open_vehicle(spec, url) if open_vehicle is not None else open_mavsdk_vehicle(
                        spec.name, spec.system_id, url, mission.origin,
                        connect_timeout_s=settings.connect_timeout_s, telemetry_hz=settings.telemetry_hz,
                        signing_key=settings.signing_key))
                    vehicles[spec.name] = await stack.enter_async_context(opened)
                    report(f"{spec.name}: connected on {url} (system id {spec.system_id})")
                ready = await get_ready(plan, vehicles, settings, checks, report)
                plan, shared_clock = ready.plan, ready.shared_clock
                ctx = FlightContext(plan, settings, log, vehicles, report, shared_clock=ready.shared_clock)
                flight = ctx
                pilots = [Pilot(ctx, spec) for spec in mission.by_priority]
                outcomes = {p.name: p.outcome for p in pilots}
                try:
                    async with asyncio.TaskGroup() as tg:
                        watcher = tg.create_task(_watch_stop(stop), name="stop-watcher")
                        flights = [tg.create_task(p.fly(), name=f"{p.name}:pilot") for p in pilots]
                        remaining = len(flights)

                        def done(_task: asyncio.Task) -> None:
                            nonlocal remaining
                            remaining -= 1
                            if remaining == 0:
                                watcher.cancel()
                        for f in flights:
                            f.add_done_callback(done)
                except BaseExceptionGroup as group:
                    raise primary_error(group) from None
        except MissionAborted as exc:
            reason, message = exc.reason, str(exc)
        except PreflightRefused:
            raise
        except CompanionError as exc:
            reason, message = _reason_of(exc), str(exc)
        log.flush()
        failsafes = sorted((e for o in outcomes.values() for e in o.failsafes),
                           key=lambda e: (e.t_sim_s is None, e.t_sim_s or 0.0))
        if reason is None and any(not e.recovered for e in failsafes):
            # Never a success over a failsafe the flight did not come back from.
            open_ = next(e for e in failsafes if not e.recovered)
            reason = "geofence" if open_.cause is FailsafeCause.GEOFENCE else "failsafe"
            message = f"vehicle {open_.vehicle!r}: the autopilot's {open_.cause.value} failsafe ({open_.mode}) was not recovered"

        summary = _score(plan, log, outcomes, reason, shared_clock)
        doc = _summary_doc(plan, summary, outcomes, reason, message, time.monotonic() - started, link)
        doc["failsafes"] = [e.summary_dict() for e in failsafes]  # recovered ones too: the run says what happened
        doc["live"]["link_events"] = _link_events(vehicles, report)
        schedule = LiveSchedule.of(plan, flight)  # the timed variant's schedule, and how far the flight fell behind it
        if schedule is not None:
            doc["live"]["schedule"] = schedule.summary_dict()
        # Seconds of pure numpy, once the vehicles are done with. Not in a worker thread: beside the
        # in-process fleet's busy loop, the GIL hand-offs of numpy calls stalled it for minutes.
        doc["occlusion_certificate"] = _certificate_doc(plan)  # the headline: the first scored pair's
        doc["occlusion_certificates"] = certificates_doc(plan.certificates)
        log_problems = tuple(log.problems())
    final_reason = reason if reason is not None else (None if summary is not None and summary.success
                                                      else (summary.reason if summary else "incomplete"))
    return RunResult(summary, doc, outcomes, final_reason, message, time.monotonic() - started,
                     tracks=_tracks(log), log_problems=log_problems)


def _link_events(vehicles: Mapping[str, Vehicle], report: Callable[[str], None]) -> dict[str, dict[str, int]]:
    """Per vehicle, what its link guard signed and kept out (MAVSDK links only), each refusal reported."""
    events = {n: v.link_events() for n, v in vehicles.items() if hasattr(v, "link_events")}
    for name, counts in events.items():
        if counts.get("signing_refused"):
            report(f"{name}: link: {counts['signing_refused']} frames dropped by the signing check "
                   "(unsigned, another key, or replayed)")
    return {n: c for n, c in events.items() if c}


def _certificate_doc(plan: FlightPlan) -> dict[str, Any] | None:
    return None if plan.certificate is None else plan.certificate.summary_dict()


def _reason_of(exc: CompanionError) -> str:
    if isinstance(exc, LinkError):
        return "link_lost"
    if isinstance(exc, CommandRefused):
        return "command_refused"
    if isinstance(exc, MissionUploadError):
        return "upload_failed"
    if isinstance(exc, VehicleNotReady):
        return "not_ready"
    return "error"


def _tracks(log: FlightLog) -> dict[str, Track]:
    return {n: Track(np.asarray(tr.t_s), np.asarray(tr.x_m), np.asarray(tr.y_m))
            for n, tr in log.tracks.items() if len(tr) >= 1}


def _score(plan: FlightPlan, log: FlightLog, outcomes: Mapping[str, PilotOutcome],
           reason: str | None, shared_clock: bool) -> RunSummary | None:
    tracks = until_last_arrival(plan.mission, _tracks(log))
    if len(tracks) < len(plan.mission.vehicles):
        return None  # some vehicle never departed: nothing was flown to score
    failure_t = max(float(tr.t_s[-1]) for tr in tracks.values()) if reason else None
    mission = plan.mission
    if shared_clock:
        # Tracks keep the clock that moves the obstacles (it may have run for a long time before
        # this flight): the time limit counts from the departure, not from the stub's start.
        t0 = min(float(tr.t_s[0]) for tr in tracks.values())
        mission = dataclasses.replace(mission, safety=dataclasses.replace(
            mission.safety, time_limit_s=mission.safety.time_limit_s + t0))
    return summarize(mission, tracks, routes=plan.routes,
                     planner_ms={n: o.planner_ms for n, o in outcomes.items()},
                     failure=reason, failure_t_s=failure_t)


def _summary_doc(plan: FlightPlan, summary: RunSummary | None, outcomes: Mapping[str, PilotOutcome],
                 reason: str | None, message: str | None, wall_s: float,
                 link: LinkRecord | None) -> dict[str, Any]:
    if summary is not None:
        doc = summary.summary_dict()
    else:
        doc = {"success": False, "success_strict": False, "reason": reason or "incomplete", "failure_t_s": None,
               "duration_s": 0.0, "vehicles": {}, "min_separation_m": None, "los_blocked_fraction": None,
               "crossing_occluded": None, "planner_ms_per_tick": None}
    if reason is not None and doc.get("reason") is None:
        doc["success"] = doc["success_strict"] = False
        doc["reason"] = reason
    # The keys `companion simulate` adds, so that the two summaries compare key for key.
    doc.setdefault("mission", plan.mission.name)
    doc.setdefault("mission_file", plan.mission.source)
    doc.setdefault("variant", plan.variant)
    doc["wall_s"] = round(wall_s, 3)
    doc["speed_factor"] = round(doc["duration_s"] / wall_s, 1) if wall_s > 0 and doc.get("duration_s") else None
    doc["live"] = {
        "message": message,
        "vehicles": {n: {"phase": o.phase, "landed": o.landed, "ticks": o.ticks,
                         "offboard_reentries": o.offboard_reentries,
                         "interventions": dict(o.interventions), "error": o.error,
                         "arrival_t_mission_s": o.arrival_t_mission_s}
                     for n, o in outcomes.items()},
        **({} if link is None else link.summary_dict()),
    }
    return doc


def save_run(out_dir: Path, plan: FlightPlan, result: RunResult, problems: tuple[str, ...] = ()) -> SaveReport:
    """summary.json, then trajectory.png, into ``out_dir``; ``problems`` are other outputs that
    are incomplete (e.g. the stub's .tlog), named in the summary with the flight logs'."""
    from companion.plots import save_trajectory
    return save_results(out_dir, result.summary_dict, [
        ("trajectory.png", lambda path: save_trajectory(path, plan.mission, result.tracks, plan.routes))],
        problems=(*result.log_problems, *problems))


def summary_table(plan: FlightPlan, result: RunResult) -> str:
    """The human summary printed on exit."""
    doc = result.summary_dict
    lines = [f"{'vehicle':<8} {'arrived':<8} {'flight s':>9} {'bound s':>8} {'ratio':>6} {'path m':>8} "
             f"{'min clear (true) m':>18} {'nodes':>9} {'plan ms':>8} {'phase':<9}"]

    def f(v, fmt):
        width = int(fmt.split(".")[0]) if fmt[:1].isdigit() else 0
        text = "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)
        return text.rjust(width)
    for spec in plan.mission.by_priority:
        v = doc.get("vehicles", {}).get(spec.name, {})
        o = result.outcomes.get(spec.name)
        nodes = "-" if v.get("nodes_raw") is None else f"{v['nodes_raw']}->{v['nodes_sparse']}"
        lines.append(f"{spec.name:<8} {str(v.get('arrived', False)):<8} {f(v.get('flight_time_s'), '9.1f')} "
                     f"{f(v.get('lower_bound_s'), '8.1f')} {f(v.get('ratio'), '6.3f')} {f(v.get('path_length_m'), '8.0f')} "
                     f"{f(v.get('min_obstacle_clearance_m'), '18.1f')} {nodes:>9} "
                     f"{f(v.get('planner_ms_per_tick'), '8.2f')} {(o.phase if o else '-'):<9}")
    verdict = "SUCCESS" if result.success else f"FAILED ({result.reason})"
    lines.append(f"run: {verdict}; min separation {f(doc.get('min_separation_m'), '.1f')} m; "
                 f"sight blocked {f(doc.get('los_blocked_fraction'), '.2f')}; "
                 f"crossing occluded {doc.get('crossing_occluded')}; wall {result.wall_s:.1f} s")
    for e in doc.get("failsafes", ()):
        when = "-" if e["t_mission_s"] is None else f"{e['t_mission_s']:.1f} s"
        lines.append(f"failsafe: {e['vehicle']} entered {e['mode']} at {when} ({e['cause']}"
                     f"{', recovered' if e['recovered'] else ', not recovered'})")
    if result.message:
        lines.append(f"why: {result.message}")
    return "\n".join(lines)
