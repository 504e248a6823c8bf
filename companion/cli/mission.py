"""``companion validate | plan | upload | schema``: a mission's checks, routes and upload, without flying."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from companion.app.event_loop import run_bounded
from companion.app.flight_plan import FlightPlan, verify_readback
from companion.cli.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK
from companion.cli.options import (add_certificate_options, add_no_fence_option, add_signing_key_option,
                                   add_variant_option, connect_pair, connections, output_dir, planned, positive,
                                   printer, quiet_mavsdk, signing_key)
from companion.errors import CompanionError, PreflightRefused
from uav_model.fence_margin import fence_warnings
from uav_model.mission import mission_schema, shared_goals


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Register validate, plan, upload and schema on the ``companion`` parser."""
    p = sub.add_parser("validate", help="check a mission file (schema, geometry, reachability)")
    p.add_argument("mission", type=Path)
    add_variant_option(p)
    add_certificate_options(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("plan", help="global routes and a plot, no vehicles")
    p.add_argument("mission", type=Path)
    add_variant_option(p)
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="write routes.json and trajectory.png here")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("upload", help="plan, upload the routes as MAVLink missions and the geofence, read them back")
    p.add_argument("mission", type=Path)
    p.add_argument("--connect", type=connect_pair, action="append", default=[], metavar="NAME=URL", required=True)
    add_variant_option(p)
    p.add_argument("--connect-timeout", type=positive, default=15.0, metavar="S")
    add_no_fence_option(p)
    add_signing_key_option(p)
    p.set_defaults(func=cmd_upload)

    p = sub.add_parser("schema", help="print the mission JSON Schema")
    p.set_defaults(func=cmd_schema)


def cmd_schema(args: argparse.Namespace) -> int:
    print(json.dumps(mission_schema(), indent=2))
    return EXIT_OK


@planned
def cmd_validate(args: argparse.Namespace, plan: FlightPlan) -> int:
    m = plan.mission
    for station, names in shared_goals(m).items():
        print(f"{m.source}: warning: vehicles {', '.join(names)} share goal station {station!r}: "
              f"only one can hold it; the others will wait near it until the time limit")
    for line in fence_warnings(m):
        print(f"{m.source}: warning: fence: {line}")
    routes = ", ".join(f"{n}: {r.nodes_raw} -> {r.nodes_sparse} nodes" for n, r in plan.routes.items())
    print(f"{m.source}: ok: {len(m.vehicles)} vehicle(s), {len(m.world.obstacles)} obstacle(s) "
          f"({len(m.world.moving_obstacles)} moving), variant {plan.variant}" + (f"; routes {routes}" if routes else ""))
    for certificate in plan.certificates:
        print(certificate.describe())
    if (advice := plan.certificate_advice()) is not None:
        print(f"  {advice}")
    return EXIT_OK


@planned
def cmd_plan(args: argparse.Namespace, plan: FlightPlan) -> int:
    from companion.planning.bounds import lower_bound_s
    from companion.planning.coordination.certificate import certificates_doc
    out = output_dir(args.out)
    doc: dict = {"mission": plan.mission.name, "variant": plan.variant, "vehicles": {}}
    for v in plan.mission.by_priority:
        nodes = plan.nodes_enu_m(v)
        route = plan.routes.get(v.name)
        bound = lower_bound_s(plan.mission.world, v.start_enu_m, v.goal_enu_m, v.speed_m_s)
        doc["vehicles"][v.name] = {
            "start": v.start, "goal": v.goal, "nodes_raw": None if route is None else route.nodes_raw,
            "nodes_sparse": None if route is None else route.nodes_sparse,
            "constraint": getattr(route, "constraint", None),
            "lower_bound_s": bound,
            "waypoints_enu_m": [[round(float(x), 3), round(float(y), 3)] for x, y in nodes],
            "waypoints_geodetic": [[round(w.lat_deg, 7), round(w.lon_deg, 7), w.alt_rel_m] for w in plan.waypoints(v)],
        }
        print(f"{v.name}: {v.start} -> {v.goal}: "
              + (f"{route.nodes_raw} A* nodes -> {route.nodes_sparse} sparse" if route else "no global route (variant)")
              + f"; lower bound {bound:.1f} s")
    if plan.certificate is not None:
        doc["occlusion_certificate"] = plan.certificate.summary_dict()  # the headline: the first scored pair's
        doc["occlusion_certificates"] = certificates_doc(plan.certificates)
    for certificate in plan.certificates:
        print(certificate.describe())
    (out / "routes.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    from companion.app.fence import mission_fence
    from companion.formats.qgc_plan import plan_document
    zones = mission_fence(plan.mission)
    for v in plan.mission.vehicles:
        doc = plan_document(plan.mission, v, plan.waypoints(v), zones)
        (out / f"{v.name}.plan").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    _save_plan_figure(out / "trajectory.png", plan)
    print(f"wrote {out / 'routes.json'}, {out / 'trajectory.png'} and a QGroundControl .plan per vehicle")
    return EXIT_OK


def _save_plan_figure(path: Path, plan: FlightPlan) -> None:
    """The world with the planned routes (nothing flown yet), moving obstacles swept over the
    longest route's time at cruise."""
    from companion.plots import place_legend, vehicle_colors, world_figure
    nodes = {v.name: plan.nodes_enu_m(v) for v in plan.mission.by_priority}
    t_end = max(sum(math.dist(p, q) for p, q in zip(nodes[v.name][:-1], nodes[v.name][1:])) / v.speed_m_s
                for v in plan.mission.vehicles)
    fig, ax = world_figure(plan.mission, title=f"{plan.mission.name}: planned routes ({plan.variant})",
                           sweep_until_s=t_end)
    colors = vehicle_colors(plan.mission)
    for v in plan.mission.by_priority:
        route = plan.routes.get(v.name)
        if route is not None and len(route.raw_enu_m) != len(nodes[v.name]):
            ax.plot(route.raw_enu_m[:, 0], route.raw_enu_m[:, 1], ls="--", lw=0.8, alpha=0.6, color=colors[v.name],
                    label=f"{v.name}: raw A* ({route.nodes_raw} nodes)")
        ax.plot(nodes[v.name][:, 0], nodes[v.name][:, 1], lw=1.4, marker="o", ms=3.5, color=colors[v.name],
                label=f"{v.name}: uploaded route ({len(nodes[v.name])} waypoints)")
    place_legend(fig, ax)
    fig.savefig(path)


@planned
def cmd_upload(args: argparse.Namespace, plan: FlightPlan) -> int:
    conns = connections(plan, args.connect)
    key = signing_key(args, conns)
    quiet_mavsdk(None)
    try:
        run_bounded(_upload(plan, conns, args.connect_timeout, key, printer(time.monotonic())))
    except PreflightRefused as exc:  # the geofence refused or read back different
        print(f"companion: refused: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except CompanionError as exc:
        print(f"companion: upload failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


async def _upload(plan: FlightPlan, conns: dict[str, str], timeout_s: float, key: bytes | None, report) -> None:
    from companion.app.fence import upload_and_verify_fence
    from companion.vehicle.mavsdk_open import open_mavsdk_vehicle
    for v in plan.mission.vehicles:
        async with open_mavsdk_vehicle(v.name, v.system_id, conns[v.name], plan.mission.origin,
                                       connect_timeout_s=timeout_s, signing_key=key) as vehicle:
            waypoints = plan.waypoints(v)
            await vehicle.upload_route(waypoints, plan.mission.planner.acceptance_radius_m)
            got = await vehicle.download_route()
            verify_readback(v.name, waypoints, got)
            report(f"{v.name}: uploaded {len(waypoints)} waypoints to {conns[v.name]} and read them back")
            await upload_and_verify_fence(vehicle, plan, report)
