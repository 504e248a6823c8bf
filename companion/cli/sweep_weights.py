"""``companion sweep weights``: fly a grid of score weights (w_h, w_d, w_s) over seeded random
scenarios and judge the paper's claim that they have little effect on flight time.

Registered under ``companion sweep`` by :func:`add_weights_parser`. It runs through the bench's
executor code (``--executor local|dask``), so it fans out the same way ``companion bench`` does.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

from companion.cli.bench import add_common_arguments, finish, fly, guarded
from companion.bench.machine import cpu_model
from companion.bench.weights import Weights, grid
from uav_model.mission import VARIANTS

SCALES = (0.5, 1.0, 2.0)  # the default grid: each of the paper's weights halved, kept, doubled
DESCRIPTION = ("Fly seeded random scenarios with every (w_h, w_d, w_s) of a grid - by default each of the "
               "paper's 0.37 / 0.6 / 0.8 halved, kept and doubled, 27 sets - and compare flight times with "
               "the paper's weights scenario by scenario. Writes runs.csv, sweep.json, table.md, "
               "weight_sweep.png and the failure gallery. Exit 1 if any run was unsafe or crashed, 2 on bad input.")


def _weight_list(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("give at least one weight")
    if any(not 0.0 <= v <= 100.0 for v in values):
        raise argparse.ArgumentTypeError(f"weights must be in [0, 100] (the mission schema's range): {text}")
    if len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(f"a weight is listed twice: {text}")
    return values


def _scaled(value: float) -> str:
    return ",".join(f"{round(value * k, 6):g}" for k in SCALES)


def add_weights_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``weights`` to ``companion sweep``'s subparsers."""
    paper = Weights.default()
    p = subparsers.add_parser("weights", help="fly a grid of score weights over random scenarios; judge the "
                                              "paper's 'little effect on flying time' claim", description=DESCRIPTION)
    add_common_arguments(p, scenarios=30, why="", out="sweep_weights_s<seed>_n<N>")
    p.add_argument("--variant", choices=VARIANTS, default="astar-bdwa", help="planner variant (default astar-bdwa)")
    for name, value in (("heading", paper.heading), ("distance", paper.distance), ("sightline", paper.sightline)):
        p.add_argument(f"--{name}", type=_weight_list, default=_weight_list(_scaled(value)), metavar="W[,W...]",
                       help=f"values of the {name} weight (default {_scaled(value)})")
    p.set_defaults(func=main)
    return p


def main(args: argparse.Namespace) -> int:
    return guarded("companion sweep weights", _sweep, args)


def _sweep(args: argparse.Namespace) -> int:
    from companion.bench import figures, sweep
    from companion.bench.table import write_runs_csv
    from companion.scenarios import config_dict

    reference = Weights.default()
    weight_sets = grid(args.heading, args.distance, args.sightline)
    if reference not in weight_sets:  # the paired comparison needs the paper's weights flown
        weight_sets = (reference, *weight_sets)
    flown = fly(args, args.out or Path(f"sweep_weights_s{args.seed}_n{args.scenarios}"), (args.variant,), weight_sets)
    rows, out = flown.rows, flown.out
    summary = sweep.summarise(rows, reference)
    judged = sweep.verdict(summary)
    write_runs_csv(rows, out / "runs.csv")
    (out / "sweep.json").write_text(json.dumps({"summary": summary, "verdict": judged}, indent=2) + "\n",
                                    encoding="utf-8")
    table = sweep.markdown_table(summary)
    text = sweep.verdict_text(judged)
    (out / "table.md").write_text(table + "\n\n" + text + "\n", encoding="utf-8")
    lists = " ".join(f"--{k} {','.join(f'{v:g}' for v in getattr(args, k))}" for k in ("heading", "distance", "sightline"))
    command = (f"companion sweep weights --scenarios {args.scenarios} --seed {args.seed} --variant {args.variant} "
               f"{lists} --plant {flown.config.plant} {flown.spec.describe()} --out {out}")
    meta = {"command": command, "seed": args.seed, "scenarios": args.scenarios, "variant": args.variant,
            "weight_sets": len(weight_sets), "executor": flown.where, "wall_s": round(flown.wall_s, 2),
            "cpu": cpu_model(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "scenario_config": config_dict(flown.config)}
    (out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    figures.save(figures.weight_sweep_figure(rows, summary), out / "weight_sweep.png")

    print(table + "\n\n" + text)
    print(f"\n{len(rows)} runs ({args.scenarios} scenarios x {len(weight_sets)} weight sets, {args.variant}, "
          f"seed {args.seed}) in {flown.wall_s:.1f} s wall on {flown.where} ({cpu_model()}); results in {out}/")
    return finish("companion sweep weights", flown)
