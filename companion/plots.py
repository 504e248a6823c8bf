"""Figures of a flight, in the paper's Fig. 4 / 9 / 12 style.

Uses matplotlib's object API on the Agg canvas directly: no pyplot, so no global figure
registry, no backend switch and nothing left behind between calls.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Polygon as PolygonPatch

from uav_model.mission import Mission
from companion.planning.metrics import Track

_TRACK_STYLES = ({"color": "tab:red", "lw": 2.4}, {"color": "tab:blue", "lw": 1.4},
                 {"color": "tab:green", "lw": 1.4}, {"color": "tab:purple", "lw": 1.4})


def _patch(polygon, **kw) -> PolygonPatch:
    return PolygonPatch(np.asarray(polygon.exterior.coords), closed=True, **kw)


def trajectory_figure(mission: Mission, tracks: Mapping[str, Track], routes: Mapping[str, object] | None = None,
                      *, title: str | None = None) -> Figure:
    """True and inflated obstacles (moving ones with their path), raw A* dashed, sparse route,
    flown tracks and stations."""
    fig = Figure(figsize=(7.0, 7.0), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    world = mission.world
    t_end = max((float(tr.t_s[-1]) for tr in tracks.values()), default=0.0)
    for o in world.obstacles:
        if o.is_moving:
            times = np.linspace(0.0, max(t_end, 1.0), 400)
            path = np.asarray(o.center) + o.offset_at(times)
            ax.plot(path[:, 0], path[:, 1], ls=":", color="0.45", lw=1.0)
            for t in np.linspace(0.0, t_end, 4):
                ax.add_patch(_patch(o.inflated_at(t), fc="none", ec="0.6", ls="--", lw=0.7))
                ax.add_patch(_patch(o.footprint_at(t), fc="0.55", ec="0.3", alpha=0.35, lw=0.7))
        else:
            ax.add_patch(_patch(o.inflated, fc="0.9", ec="0.6", ls="--", lw=0.8))
            ax.add_patch(_patch(o.footprint, fc="0.55", ec="0.25", lw=0.8))
    for i, (name, tr) in enumerate(tracks.items()):
        style = _TRACK_STYLES[i % len(_TRACK_STYLES)]
        route = None if routes is None else routes.get(name)
        if route is not None:
            raw, sparse = np.asarray(route.raw_enu_m), np.asarray(route.sparse_enu_m)
            ax.plot(raw[:, 0], raw[:, 1], ls="--", lw=0.8, color=style["color"], alpha=0.6,
                    label=f"{name}: raw A* ({len(raw)} nodes)")
            ax.plot(sparse[:, 0], sparse[:, 1], ls="-", lw=0.8, marker="o", ms=3.5, color="k", alpha=0.7,
                    label=f"{name}: sparse ({len(sparse)} nodes)")
        ax.plot(tr.x_m, tr.y_m, label=f"{name}: flown ({float(tr.t_s[-1] - tr.t_s[0]):.1f} s)", **style)
    for label, (x, y) in mission.stations.items():
        ax.plot([x], [y], marker="^", ms=9, color="k")
        ax.annotate(label, (x, y), textcoords="offset points", xytext=(6, 6), fontsize=11, weight="bold")
    fx0, fy0, fx1, fy1 = world.geofence.bounds
    ax.plot([fx0, fx1, fx1, fx0, fx0], [fy0, fy0, fy1, fy1, fy0], color="0.7", lw=0.6)
    ax.set_xlim(fx0, fx1)
    ax.set_ylim(fy0, fy1)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(title or mission.name)
    ax.legend(loc="lower right", fontsize=7, framealpha=0.85)
    ax.grid(True, lw=0.3, alpha=0.5)
    fig.tight_layout()
    return fig


def save_trajectory(path: str | Path, mission: Mission, tracks: Mapping[str, Track],
                    routes: Mapping[str, object] | None = None, *, title: str | None = None) -> Path:
    """Write trajectory.png (or any extension matplotlib knows) and return its path."""
    path = Path(path)
    trajectory_figure(mission, tracks, routes, title=title).savefig(path)
    return path
