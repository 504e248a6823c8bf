"""``companion``: the command line.

    companion simulate MISSION.yaml [--variant V] [--out DIR]   headless flight, summary + plot
    companion sweep table1|table2|table3 [--out DIR]            the paper's Tables I-III
    companion sweep weights                                     score weights vs flight time (companion.bench)
    companion run | validate | plan | upload | schema           flying commands (companion.app)
    companion bench                                             the Table IV ablation (companion.bench)
    companion import | replay                                   .plan / GeoJSON in, an animation out

Exit codes, for every subcommand:

    0  success
    1  mission failure (the flight did not succeed)
    2  bad input: one line naming the problem (``file:line: field.path: reason``), no traceback

Each subcommand module registers its own parsers; a handler is stored as ``func`` (or ``handler``)
and returns the exit code. To add one, add a registration entry to ``_COMMAND_MODULES``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from companion.cli_common import (EXIT_FAILED, EXIT_OK, BadInput, add_plant_option, add_variant_option, bad_input,
                                  output_dir, with_plant)
from uav_model.mission import Mission, MissionError, load_mission
from companion.planning.errors import NoPath

# (module, registration function) of the other subcommand groups, each f(subparsers) -> None.
_COMMAND_MODULES = (
    ("companion.commands", "add_commands"),  # run, validate, plan, upload, schema
    ("companion.bench.cli", "add_parser"),  # bench
    ("companion.formats.cli", "add_parsers"),  # import, replay
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="companion", description="A*-BDWA cooperative obstacle avoidance for a pair of UAVs.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_simulate(sub)
    _add_sweep(sub)
    for module_name, function in _COMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:  # a real import error inside the module: show it
                raise
            continue  # that command group is not installed in this checkout
        getattr(module, function)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = getattr(args, "func", None) or args.handler
    try:
        return int(handler(args))
    except BadInput as exc:
        return bad_input(exc)
    except KeyboardInterrupt:
        print("companion: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `companion simulate ... | head`: the reader left, not an error
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


# --- simulate ------------------------------------------------------------------------------------

def _add_simulate(sub) -> None:
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
    from companion.planning.flight.headless import simulate_certified
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
        warm_up_headless(mission, args.variant)  # compiled code loaded before the clock: the speed is the flight's
        run, certificate = simulate_certified(mission, args.variant)
    except (MissionError, NoPath) as exc:
        if made:  # bad input leaves nothing behind
            with contextlib.suppress(OSError):
                out.rmdir()
        return bad_input(exc)
    summary = run.summary.summary_dict()
    summary.update(mission=mission.name, mission_file=str(args.mission), variant=run.variant,
                   wall_s=round(run.wall_s, 3), speed_factor=round(run.speed_factor, 1))
    summary["occlusion_certificate"] = None if certificate is None else certificate.summary_dict()
    print(format_summary(run), flush=True)  # the verdict first: it needs no disk
    if certificate is not None:
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


def _f(value, fmt: str = ".1f", none: str = "-") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return none
    return format(value, fmt)


def format_summary(run) -> str:
    """A short human table of one headless run."""
    s = run.summary
    head = "SUCCESS" if s.success else f"FAILED ({s.reason} at {_f(s.failure_t_s)} s)"
    strict = {True: "strict: yes", False: "strict: no (sight line open at closest approach)", None: ""}
    lines = [f"{run.mission.name} [{run.variant}]: {head}  {strict[s.crossing_occluded] if s.success else ''}".rstrip(),
             f"{'vehicle':8} {'arrived':7} {'time_s':>7} {'bound_s':>7} {'ratio':>6} {'path_m':>7} "
             f"{'min clear (true) m':>18} {'nodes':>9} {'ms/tick':>7}"]
    for name, v in s.vehicles.items():
        nodes = "-" if v.nodes_raw is None else f"{v.nodes_raw}/{v.nodes_sparse}"
        lines.append(f"{name:8} {'yes' if v.arrived else 'no':7} {v.flight_time_s:7.1f} {_f(v.lower_bound_s):>7} "
                     f"{_f(v.ratio, '.3f'):>6} {v.path_length_m:7.0f} {_f(v.min_obstacle_clearance_m):>18} "
                     f"{nodes:>9} {_f(v.planner_ms_per_tick, '.3f'):>7}")
    if s.min_separation_m is not None:
        lines.append(f"min separation {s.min_separation_m:.0f} m, sight line blocked "
                     f"{100 * s.los_blocked_fraction:.1f} % of ticks, crossing occluded: "
                     f"{'yes' if s.crossing_occluded else 'no'}")
    lines.append(f"{s.duration_s:.1f} s simulated in {run.wall_s:.2f} s wall ({run.speed_factor:.0f}x real time)")
    return "\n".join(lines)


# --- sweep: the paper's Tables I-III -------------------------------------------------------------

# The paper's numbers (section VI.B), as printed: (row label, UAV a time s, UAV b time s).
PAPER_TABLES = {
    "table1": ("Table I: initial headings a / b = a - 180 deg",
               [("0", 519.0, 693.0), ("18", 495.0, 663.0), ("36", 492.0, 672.0), ("54", 492.0, 675.0),
                ("72", 490.5, 642.0), ("90", 489.0, 688.5)]),
    "table2": ("Table II: speed of UAV a (m/s)", [("10", 472.0, 640.0), ("20", 472.0, 558.0), ("30", 474.0, 476.0)]),
    "table3": ("Table III: |OA| (m), B on the same diagonal with |OB| = 1000 m",
               [("1000", 235.0, 234.0), ("2000", 349.0, 325.0), ("3000", 422.0, 535.0), ("4000", 521.0, 733.0)]),
}
TABLE3_OB_M = 1000.0  # see docs/results-reference.md: the |OB| that fits the paper's own a-times


def _with_vehicle(mission: Mission, name: str, **changes) -> Mission:
    vehicles = tuple(dataclasses.replace(v, **changes) if v.name == name else v for v in mission.vehicles)
    return dataclasses.replace(mission, vehicles=vehicles)


def table_missions(table: str, base: Mission) -> list[tuple[str, Mission]]:
    """The reference mission varied as the paper's table does: (row label, mission) pairs."""
    a, b = (v.name for v in base.by_priority[:2])
    rows = []
    for label, _, _ in PAPER_TABLES[table][1]:
        value = float(label)
        if table == "table1":
            m = _with_vehicle(_with_vehicle(base, a, initial_heading_deg=value), b, initial_heading_deg=value - 180.0)
        elif table == "table2":
            m = _with_vehicle(base, a, speed_m_s=value)
        else:
            m = _diagonal_mission(base, value, TABLE3_OB_M)
        rows.append((label, dataclasses.replace(m, name=f"{base.name}_{table}_{label}")))
    return rows


def _diagonal_mission(base: Mission, oa_m: float, ob_m: float) -> Mission:
    """A at the origin, the (single) obstacle's centre at |OA| and B at |OA| + |OB| on the
    45 deg diagonal; the area is the square with A and B at opposite corners."""
    from shapely import affinity

    from uav_model.world import World
    (obstacle,) = base.world.obstacles
    a, b = (v.name for v in base.by_priority[:2])
    k = 1.0 / math.sqrt(2.0)
    o_xy = (oa_m * k, oa_m * k)
    side = (oa_m + ob_m) * k
    moved = dataclasses.replace(obstacle, center=o_xy, footprint=affinity.translate(
        obstacle.footprint, o_xy[0] - obstacle.center[0], o_xy[1] - obstacle.center[1]))
    world = World(0.0, 0.0, side, side, base.world.geofence_margin_m, (moved,))
    start_a = base.vehicle(a).start
    start_b = base.vehicle(b).start
    stations = {start_a: (0.0, 0.0), start_b: (side, side)}
    m = dataclasses.replace(base, world=world, stations=stations)
    m = _with_vehicle(m, a, start_enu_m=(0.0, 0.0), goal_enu_m=(side, side))
    return _with_vehicle(m, b, start_enu_m=(side, side), goal_enu_m=(0.0, 0.0))


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="the paper's Tables I-III beside its numbers, or a score-weight sweep",
                       description="table1|table2|table3: vary the reference mission as the paper's table does, "
                                   "fly each row headless and print our flight times beside the paper's. "
                                   "weights: fly a grid of score weights over seeded random scenarios.")
    sweeps = p.add_subparsers(dest="sweep", required=True, metavar="SWEEP")
    for table in sorted(PAPER_TABLES):
        t = sweeps.add_parser(table, help=PAPER_TABLES[table][0],
                              description=f"Reproduce the paper's {PAPER_TABLES[table][0]}, headless.")
        t.add_argument("--mission", type=Path, default=Path("missions/paper_reference.yaml"),
                       help="the reference mission to vary (default missions/paper_reference.yaml)")
        add_variant_option(t)
        add_plant_option(t)
        t.add_argument("--out", type=Path, default=None, metavar="DIR",
                       help="write <table>.json and a trajectory per row here")
        t.set_defaults(func=cmd_sweep, table=table)
    try:
        from companion.bench.sweep_cli import add_weights_parser
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith("companion.bench"):
            raise
        return  # the bench is not installed in this checkout
    add_weights_parser(sweeps)


def cmd_sweep(args: argparse.Namespace) -> int:
    try:
        base = with_plant(load_mission(args.mission), args.plant)
    except MissionError as exc:
        return bad_input(exc)
    if len(base.vehicles) < 2 or (args.table == "table3" and len(base.world.obstacles) != 1):
        return bad_input(MissionError(str(args.mission), "vehicles" if len(base.vehicles) < 2 else "obstacles",
                                      "the sweeps vary the paper's scenario: two vehicles and (table3) one obstacle"))
    if args.out is not None:
        output_dir(args.out)
    from companion.planning.flight.headless import simulate  # after the input checks: they need neither
    from companion.plots import save_trajectory

    title, paper = PAPER_TABLES[args.table]
    a, b = (v.name for v in base.by_priority[:2])
    print(title)
    print(f"{'row':>6} | {'paper a':>7} {'ours a':>7} {'bound a':>7} | {'paper b':>7} {'ours b':>7} "
          f"{'bound b':>7} | result")
    results = []
    all_ok = True
    for (label, mission), (_, paper_a, paper_b) in zip(table_missions(args.table, base), paper):
        try:
            run = simulate(mission, args.variant)
        except NoPath as exc:
            print(f"{label:>6} | no path: {exc}")
            all_ok = False
            continue
        s = run.summary
        va, vb = s.vehicles[a], s.vehicles[b]
        verdict = "ok" if s.success else s.reason
        all_ok &= s.success
        print(f"{label:>6} | {paper_a:7.1f} {va.flight_time_s:7.1f} {_f(va.lower_bound_s):>7} | "
              f"{paper_b:7.1f} {vb.flight_time_s:7.1f} {_f(vb.lower_bound_s):>7} | {verdict}, "
              f"LOS blocked {100 * (s.los_blocked_fraction or 0):.0f} %")
        row = {"row": label, "paper_a_s": paper_a, "paper_b_s": paper_b, "summary": s.summary_dict()}
        results.append(row)
        if args.out is not None:
            save_trajectory(args.out / f"{args.table}_{label}.png", mission, run.tracks, run.routes,
                            title=f"{title.split(':')[0]}, row {label}")
    if args.out is not None:
        (args.out / f"{args.table}.json").write_text(json.dumps({"table": title, "rows": results}, indent=2) + "\n",
                                                     encoding="utf-8")
    return EXIT_OK if all_ok else EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
