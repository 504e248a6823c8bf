"""``companion import`` and ``companion replay``: the ecosystem's formats on the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.cli.errors import EXIT_OK, BadInput
from companion.formats.importer import ImportError_, import_mission
from uav_model.mission import MissionError


def add_parsers(sub) -> None:
    p = sub.add_parser("import", help="a QGroundControl .plan or a GeoJSON file to mission YAML")
    p.add_argument("file", type=Path, help="FILE.plan or FILE.geojson")
    p.add_argument("--out", type=Path, required=True, help="the mission YAML to write")
    p.add_argument("--base", type=Path, default=None,
                   help="a mission whose stations, vehicles, planner and safety settings to keep")
    p.set_defaults(func=cmd_import)
    p = sub.add_parser("replay", help="render a flown run (flight.csv, traffic.csv) as an animation")
    p.add_argument("out_dir", type=Path, help="the --out directory of a run or simulate")
    p.add_argument("--mission", type=Path, default=None, help="the mission flown (default: summary.json's)")
    p.add_argument("--output", type=Path, default=None, help="FILE.gif (default OUT_DIR/replay.gif)")
    p.add_argument("--fps", type=int, default=15)
    p.add_argument("--seconds", type=float, default=12.0, help="length of the animation")
    p.set_defaults(func=cmd_replay)


def cmd_import(args: argparse.Namespace) -> int:
    from companion.scenarios import write_mission_yaml
    try:
        doc, mission = import_mission(args.file, args.base)
    except (ImportError_, MissionError) as exc:
        raise BadInput(str(exc)) from None  # "companion: " before even a MissionError's line
    doc.setdefault("description", f"imported from {args.file.name}")
    try:
        path = write_mission_yaml(doc, args.out)
    except OSError as exc:
        raise BadInput(f"--out {args.out}: cannot write ({exc.strerror})") from None
    print(f"wrote {path}: {len(mission.world.obstacles)} obstacle(s), {len(mission.stations)} station(s), "
          f"{len(mission.vehicles)} vehicle(s)")
    return EXIT_OK


def cmd_replay(args: argparse.Namespace) -> int:
    from companion.replay import ReplayError, render_replay
    try:
        path = render_replay(args.out_dir, mission_path=args.mission, output=args.output,
                             fps=args.fps, seconds=args.seconds)
    except (ReplayError, MissionError) as exc:
        raise BadInput(str(exc)) from None
    print(f"wrote {path}")
    return EXIT_OK
