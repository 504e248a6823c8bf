"""``companion simulate``: fly a mission headless (no sockets) and score it."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from pathlib import Path

from companion.cli.errors import EXIT_FAILED, EXIT_OK, bad_input
from companion.cli.options import add_plant_option, add_variant_option, output_dir, with_plant
from companion.planning.errors import NoPath
from uav_model.mission import MissionError, load_mission


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="fly the mission headless (no sockets) and score it",
                       description="Fly every vehicle of the mission in-process with the same planner and "
                                   "plant as the live companion; write summary.json and trajectory.png.")
    p.add_argument("mission", type=Path)
    add_variant_option(p)
    add_plant_option(p)
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output directory (default: simulate-<mission>-<variant>)")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args: argparse.Namespace) -> int:
    from companion.app.results import save_results
    from companion.app.warmup import warm_up_headless
    from companion.planning.coordination.certificate import certificates_doc
    from companion.planning.flight.headless import flight_inputs, simulate_certified
    from companion.plots import save_trajectory

    try:
        mission = with_plant(load_mission(args.mission), args.plant)
    except MissionError as exc:
        return bad_input(exc)
    variant = args.variant or mission.planner.variant
    out_path = args.out or Path(f"simulate-{mission.name}-{variant}")
    made = not out_path.exists()
    out = output_dir(out_path)  # before flying: minutes lost otherwise
    try:
        mission = mission.with_variant(variant)
        inputs = flight_inputs(mission)  # routes and the first vehicle's forecast: flown once, used twice
        warm_up_headless(mission, inputs=inputs)  # compiled code loaded before the clock: the speed is the flight's
        run, certificates = simulate_certified(mission, inputs=inputs)
    except (MissionError, NoPath) as exc:
        if made:  # bad input leaves nothing behind
            with contextlib.suppress(OSError):
                out.rmdir()
        return bad_input(exc)
    summary = run.summary.summary_dict()
    summary.update(mission=mission.name, mission_file=str(args.mission), variant=run.variant,
                   wall_s=round(run.wall_s, 3), speed_factor=round(run.speed_factor, 1))
    summary["occlusion_certificate"] = certificates[0].summary_dict() if certificates else None  # the headline
    summary["occlusion_certificates"] = certificates_doc(certificates)
    print(format_summary(run), flush=True)  # the verdict first: it needs no disk
    for certificate in certificates:
        print(certificate.describe(), flush=True)
    saved = save_results(out, summary, [
        ("trajectory.png", lambda path: save_trajectory(path, mission, run.tracks, run.routes,
                                                        title=f"{mission.name} ({run.variant})")),
        ("flight.csv", lambda path: _write_flight_log(path, run.tracks))])
    print(saved.line(), file=sys.stdout if saved.complete else sys.stderr, flush=True)
    return EXIT_OK if run.success else EXIT_FAILED


def _write_flight_log(path: Path, tracks) -> None:
    """flight.csv in `companion run`'s columns (pose per tick; the obstacles' clock is the
    mission's), so that `companion replay` reads a simulate directory as it reads a run."""
    import csv
    from companion.app.flight_log import FLIGHT_COLUMNS
    rows = sorted((float(t), name, float(x), float(y)) for name, tr in tracks.items()
                  for t, x, y in zip(tr.t_s, tr.x_m, tr.y_m))
    with open(path, "w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(FLIGHT_COLUMNS)
        for t, name, x, y in rows:
            row = dict(t_mission_s=f"{t:.3f}", t_sim_s=f"{t:.3f}", vehicle=name, phase="simulate",
                       x_m=f"{x:.3f}", y_m=f"{y:.3f}")
            out.writerow([row.get(c, "") for c in FLIGHT_COLUMNS])


def shown(value, fmt: str = ".1f", none: str = "-") -> str:
    """``value`` formatted, or ``none`` for a missing or non-finite one."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return none
    return format(value, fmt)


def format_summary(run) -> str:
    """A short human table of one headless run."""
    s = run.summary
    head = "SUCCESS" if s.success else f"FAILED ({s.reason} at {shown(s.failure_t_s)} s)"
    strict = "" if not (s.success and s.sight_pairs) else \
        "strict: yes" if s.success_strict else "strict: no (sight line open at closest approach)"
    lines = [f"{run.mission.name} [{run.variant}]: {head}  {strict}".rstrip(),
             f"{'vehicle':8} {'arrived':7} {'time_s':>7} {'bound_s':>7} {'ratio':>6} {'path_m':>7} "
             f"{'min clear (true) m':>18} {'nodes':>9} {'ms/tick':>7}"]
    for name, v in s.vehicles.items():
        nodes = "-" if v.nodes_raw is None else f"{v.nodes_raw}/{v.nodes_sparse}"
        lines.append(f"{name:8} {'yes' if v.arrived else 'no':7} {v.flight_time_s:7.1f} {shown(v.lower_bound_s):>7} "
                     f"{shown(v.ratio, '.3f'):>6} {v.path_length_m:7.0f} {shown(v.min_obstacle_clearance_m):>18} "
                     f"{nodes:>9} {shown(v.planner_ms_per_tick, '.3f'):>7}")
    if s.min_separation_m is not None:
        lines.append(f"min separation {s.min_separation_m:.0f} m, sight line blocked "
                     f"{100 * s.los_blocked_fraction:.1f} % of ticks, crossing occluded: "
                     f"{'yes' if s.crossing_occluded else 'no'}")
    if len(s.sight_pairs) > 1:  # the headline above is the first pair's
        lines.append("sight pairs: " + "; ".join(
            f"{p} blocked {100 * s.pairs[p].los_blocked_fraction:.1f} %, at closest approach "
            f"{'yes' if s.pairs[p].crossing_occluded else 'no'}" for p in s.sight_pairs))
    lines.append(f"{s.duration_s:.1f} s simulated in {run.wall_s:.2f} s wall ({run.speed_factor:.0f}x real time)")
    return "\n".join(lines)
