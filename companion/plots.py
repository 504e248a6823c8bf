"""Figures of a flight, in the paper's Fig. 4 / 9 / 12 style, and the pieces the replay shares.

Uses matplotlib's object API on the Agg canvas directly: no pyplot, so no global figure
registry, no backend switch and nothing left behind between calls.

One source of truth for what every picture shows the same way: :func:`vehicle_colors` (a
vehicle's colour, by its place in the mission), :func:`draw_world` (area, geofence, obstacles,
stations), :func:`add_geodetic_axes` (lat/lon ticks) and :func:`place_legend` (below the axes,
so it never covers a station).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Polygon as PolygonPatch
from shapely.ops import unary_union

from uav_model import frames
from uav_model.mission import Mission
from companion.planning.metrics import Track

# tab10 without its grey (the obstacles' colour), then tab20's light halves: 18 distinct colours.
_PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink",
            "tab:olive", "tab:cyan", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94",
            "#f7b6d2", "#dbdb8d", "#9edae5")
_SWEEP_SAMPLES = 120


def vehicle_colors(mission: Mission) -> dict[str, str]:
    """Each vehicle's colour in every figure and animation, by its place in the mission's list."""
    return {v.name: _PALETTE[i % len(_PALETTE)] for i, v in enumerate(mission.vehicles)}


def _patch(polygon, **kw) -> PolygonPatch:
    return PolygonPatch(np.asarray(polygon.exterior.coords), closed=True, **kw)


def swept_footprint(obstacle, t0_s: float, t1_s: float):
    """Everywhere a moving obstacle's true footprint is between two times (a shapely geometry)."""
    times = np.linspace(t0_s, max(t1_s, t0_s), _SWEEP_SAMPLES)
    return unary_union([obstacle.footprint_at(float(t)) for t in times])


def _fill(ax, geometry, **kw) -> None:
    for part in getattr(geometry, "geoms", [geometry]):
        ax.add_patch(_patch(part, **kw))
        kw.pop("label", None)  # one legend entry per call


def draw_world(ax, mission: Mission, *, sweep_until_s: float | None) -> None:
    """Area, geofence, static obstacles (true and inflated), stations; and, when ``sweep_until_s``
    is given, each moving obstacle's swept path from t = 0 until then (faint). Without it the
    moving obstacles are left to the caller, which draws them where they are."""
    world = mission.world
    statics, movers = world.static_obstacles, world.moving_obstacles
    for k, o in enumerate(statics):
        ax.add_patch(_patch(o.inflated, fc="0.9", ec="0.6", ls="--", lw=0.8,
                            label=None if k else "obstacle + safety margin"))
        ax.add_patch(_patch(o.footprint, fc="0.55", ec="0.25", lw=0.8, label=None if k else "obstacle"))
    if sweep_until_s is not None:
        for k, o in enumerate(movers):
            _fill(ax, swept_footprint(o, 0.0, sweep_until_s), fc="0.55", ec="0.45", alpha=0.18, lw=0.5,
                  label=None if k else "moving obstacle: where it went")
    x0, y0, x1, y1 = world.x_min_m, world.y_min_m, world.x_max_m, world.y_max_m
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="0.35", lw=0.8, label="area")
    fx0, fy0, fx1, fy1 = world.geofence.bounds
    ax.plot([fx0, fx1, fx1, fx0, fx0], [fy0, fy0, fy1, fy1, fy0], color="k", ls=(0, (6, 3)), lw=0.9,
            label=f"geofence (area + {world.geofence_margin_m:g} m)")
    for label, (x, y) in mission.stations.items():
        ax.plot([x], [y], marker="^", ms=9, color="k")
        ax.annotate(label, (x, y), textcoords="offset points", xytext=(6, 6), fontsize=11, weight="bold")
    pad = 0.03 * max(fx1 - fx0, fy1 - fy0)
    ax.set_xlim(fx0 - pad, fx1 + pad)
    ax.set_ylim(fy0 - pad, fy1 + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.grid(True, lw=0.3, alpha=0.5)


def add_geodetic_axes(ax, origin: frames.GeoOrigin) -> None:
    """Longitude ticks on top and latitude ticks on the right, through uav_model.frames (along the
    axes through the origin: over a mission's few kilometres the grid's tilt is far below a tick)."""
    lon = np.vectorize(lambda x: frames.local_to_geodetic(origin, float(x), 0.0)[1])
    east = np.vectorize(lambda v: frames.geodetic_to_local(origin, origin.lat_deg, float(v))[0])
    lat = np.vectorize(lambda y: frames.local_to_geodetic(origin, 0.0, float(y))[0])
    north = np.vectorize(lambda v: frames.geodetic_to_local(origin, float(v), origin.lon_deg)[1])
    top = ax.secondary_xaxis("top", functions=(lon, east))
    right = ax.secondary_yaxis("right", functions=(lat, north))
    top.set_xlabel("longitude (deg)", fontsize=8)
    right.set_ylabel("latitude (deg)", fontsize=8)
    for axis in (top.xaxis, right.yaxis):
        axis.get_major_formatter().set_useOffset(False)
        axis.set_tick_params(labelsize=7)


def place_legend(fig: Figure, ax) -> None:
    """The legend of what is drawn, under the axes (never over a station); nothing drawn, none."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=7, frameon=False)


def world_figure(mission: Mission, *, title: str, sweep_until_s: float | None) -> tuple[Figure, object]:
    """A figure with the world drawn and geodetic ticks; the caller adds flights and the legend."""
    rows = (len(mission.vehicles) * 3 + 5 + 2) // 3
    fig = Figure(figsize=(7.0, 7.2 + 0.16 * rows), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    draw_world(ax, mission, sweep_until_s=sweep_until_s)
    add_geodetic_axes(ax, mission.origin)
    ax.set_title(title, fontsize=11)
    return fig, ax


def trajectory_figure(mission: Mission, tracks: Mapping[str, Track], routes: Mapping[str, object] | None = None,
                      *, title: str | None = None) -> Figure:
    """The world (moving obstacles as their swept path), each vehicle's raw A* (dashed), sparse
    route (dots) and flown track in its own colour, and the stations."""
    t_end = max((float(tr.t_s[-1]) for tr in tracks.values() if len(tr.t_s)), default=0.0)
    fig, ax = world_figure(mission, title=title or mission.name, sweep_until_s=t_end)
    colors = vehicle_colors(mission)
    for name, tr in tracks.items():
        color = colors.get(name, "k")
        route = None if routes is None else routes.get(name)
        if route is not None:
            raw, sparse = np.asarray(route.raw_enu_m), np.asarray(route.sparse_enu_m)
            ax.plot(raw[:, 0], raw[:, 1], ls="--", lw=0.8, color=color, alpha=0.6,
                    label=f"{name}: raw A* ({len(raw)} nodes)")
            ax.plot(sparse[:, 0], sparse[:, 1], ls=":", lw=0.9, marker="o", ms=3.5, color=color, mec="k", mew=0.5,
                    label=f"{name}: sparse ({len(sparse)} nodes)")
        if len(tr.t_s):
            ax.plot(tr.x_m, tr.y_m, color=color, lw=1.8,
                    label=f"{name}: flown ({float(tr.t_s[-1] - tr.t_s[0]):.1f} s)")
    place_legend(fig, ax)
    return fig


def save_trajectory(path: str | Path, mission: Mission, tracks: Mapping[str, Track],
                    routes: Mapping[str, object] | None = None, *, title: str | None = None) -> Path:
    """Write trajectory.png (or any extension matplotlib knows) and return its path."""
    path = Path(path)
    trajectory_figure(mission, tracks, routes, title=title).savefig(path)
    return path
