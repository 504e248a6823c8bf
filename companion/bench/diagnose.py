"""Why did a run fail? A few named facts per run, for runs.csv and the failure analysis.

- ``failed_vehicles``: who broke the rule (collision: the vehicle touching an obstacle; geofence:
  the vehicle outside; timeout: the vehicles that never arrived; separation: all).
- ``hit_obstacle`` / ``hit_moving`` / ``hit_from_behind``: for a collision, the obstacle whose
  true footprint is nearest the vehicle at the failure instant, whether it moves, and whether it
  came from behind (its centre behind the vehicle's heading) - the tell-tale of a moving
  obstacle that the constant-speed vehicle could not outrun or turn away from.
- ``no_rollout_ticks``: ticks in which a vehicle found no legal rollout, so it hovered or yawed
  in place (SPEC §1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from shapely.geometry import Point

from uav_model.mission import Mission


def no_rollout_ticks(ticks: Mapping[str, Sequence[Any]]) -> int:
    """Ticks (summed over vehicles) in which a not-yet-arrived vehicle had no legal rollout (no command)."""
    return sum(1 for rs in ticks.values() for r in rs if r.command is None and not r.arrived)


def diagnose(mission: Mission, tracks: Mapping[str, Any], summary: Mapping[str, Any]) -> dict[str, Any]:
    """Facts about a finished run from its tracks and summary_dict (see module docstring)."""
    reason = summary.get("reason")
    out: dict[str, Any] = {"failed_vehicles": None, "hit_obstacle": None, "hit_moving": None,
                           "hit_from_behind": None}
    if reason is None:
        return out
    names = list(tracks)
    if reason == "timeout" or reason == "incomplete":
        late = [n for n in names if not summary["vehicles"][n]["arrived"]]
        out["failed_vehicles"] = ";".join(late)
    elif reason == "geofence":
        world = mission.world
        out["failed_vehicles"] = ";".join(
            n for n in names if not world.inside_geofence(float(tracks[n].x_m[-1]), float(tracks[n].y_m[-1])))
    elif reason == "separation":
        out["failed_vehicles"] = ";".join(names)
    elif reason == "collision":
        best = None
        for n in names:
            tr = tracks[n]
            t = float(tr.t_s[-1])
            p = Point(float(tr.x_m[-1]), float(tr.y_m[-1]))
            for o in mission.world.obstacles:
                d = o.footprint_at(t).distance(p)
                if best is None or d < best[0]:
                    best = (d, n, o, t)
        if best is not None:
            _, n, o, t = best
            tr = tracks[n]
            out.update(failed_vehicles=n, hit_obstacle=o.id, hit_moving=o.is_moving)
            if o.is_moving and len(tr) >= 2:
                hx, hy = float(tr.x_m[-1] - tr.x_m[-2]), float(tr.y_m[-1] - tr.y_m[-2])
                cx, cy = o.center_at(t)
                ahead = hx * (cx - float(tr.x_m[-1])) + hy * (cy - float(tr.y_m[-1]))
                out["hit_from_behind"] = bool(ahead < 0.0) if math.hypot(hx, hy) > 0 else None
    return out
