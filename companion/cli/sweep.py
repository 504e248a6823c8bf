"""``companion sweep``: the paper's Tables I-III beside its numbers (``table1|table2|table3``),
and the score-weight sweep (``weights``, :mod:`companion.cli.sweep_weights`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from companion.bench.paper_tables import PAPER_TABLES, table_missions
from companion.cli.errors import EXIT_FAILED, EXIT_OK, bad_input
from companion.cli.options import add_plant_option, add_variant_option, output_dir, with_plant
from companion.cli.simulate import shown
from companion.cli.sweep_weights import add_weights_parser
from companion.planning.errors import NoPath
from uav_model.mission import MissionError, load_mission


def add_parser(sub) -> None:
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
        print(f"{label:>6} | {paper_a:7.1f} {va.flight_time_s:7.1f} {shown(va.lower_bound_s):>7} | "
              f"{paper_b:7.1f} {vb.flight_time_s:7.1f} {shown(vb.lower_bound_s):>7} | {verdict}, "
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
