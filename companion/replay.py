"""``companion replay OUT_DIR``: a flown run as an animated GIF.

Reads what a run wrote as it flew -- ``flight.csv`` (each vehicle's pose per planner tick, plus
event rows such as "telemetry stale", which carry no pose and are skipped), ``traffic.csv``
(ADS-B reports of moving obstacles, optional) and ``summary.json`` (which mission, optional with
``--mission``) -- from ``companion run`` (embedded stub, ``--connect``, in-process; finished or
stopped) and from ``companion simulate``.

The frames are drawn like the trajectory plot (same colours, area, geofence, lat/lon ticks):
moving obstacles where they are at the frame's time, the ADS-B reports near that time as
crosses, each vehicle's trail and position, and the sight line between the first two vehicles,
solid while open and dotted while an obstacle blocks it. The world is drawn once; each frame
redraws only what moves (blitting), so the cost is the frame count, not the flight's length.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
from shapely.geometry import LineString

from companion.plots import place_legend, vehicle_colors, world_figure
from uav_model.mission import Mission, load_mission

MAX_FRAMES = 600


class ReplayError(ValueError):
    """A run directory that cannot be replayed; ``str()`` names the file and the problem."""


def _read_csv(path: Path) -> list[dict[str, str]]:
    try:
        with path.open(newline="", encoding="utf-8") as f:
            return list(csv.DictReader(f))
    except FileNotFoundError:
        raise ReplayError(f"{path}: not found (replay reads the --out directory of `companion run` "
                          f"or `companion simulate`)") from None


def _number(text: str | None) -> float:
    """A CSV cell as a float; empty or unreadable cells (event rows, a cut-off last line) are NaN."""
    try:
        value = float(text) if text else math.nan
    except ValueError:
        return math.nan
    return value if math.isfinite(value) else math.nan


def _tracks(rows: list[dict[str, str]], path: Path) -> dict[str, np.ndarray]:
    """Per vehicle, an (N, 4) array of t_mission_s, x, y, t_sim_s in time order, from the rows
    that carry a pose. A missing t_sim_s is the mission time plus the run's usual offset."""
    if rows and not {"vehicle", "t_mission_s", "x_m", "y_m"} <= set(rows[0]):
        raise ReplayError(f"{path}: not a flight log (columns t_mission_s, vehicle, x_m, y_m expected)")
    by: dict[str, list[tuple[float, float, float, float]]] = {}
    for r in rows:
        t, x, y = _number(r.get("t_mission_s")), _number(r.get("x_m")), _number(r.get("y_m"))
        if not (math.isnan(t) or math.isnan(x) or math.isnan(y)) and r.get("vehicle"):
            by.setdefault(r["vehicle"], []).append((t, x, y, _number(r.get("t_sim_s"))))
    if not by:
        raise ReplayError(f"{path}: no pose rows: nothing was flown")
    tracks = {name: np.array(sorted(v)) for name, v in by.items()}
    every = np.concatenate(list(tracks.values()))
    offsets = every[:, 3] - every[:, 0]
    offset = float(np.median(offsets[np.isfinite(offsets)])) if np.isfinite(offsets).any() else 0.0
    for tr in tracks.values():
        tr[np.isnan(tr[:, 3]), 3] = tr[np.isnan(tr[:, 3]), 0] + offset
    return tracks


def _mission(out_dir: Path, mission_path: Path | None) -> Mission:
    if mission_path is not None:
        return load_mission(mission_path)
    summary = out_dir / "summary.json"
    try:
        doc = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ReplayError(f"{summary}: cannot read ({exc}); give --mission MISSION.yaml") from None
    source = doc.get("mission_file")
    # As written (relative to where the run started), else beside the run directory.
    for candidate in ([Path(source), out_dir / source, out_dir.parent / source] if source else []):
        if candidate.is_file():
            return load_mission(candidate)
    raise ReplayError(f"{summary}: names no mission file that exists here ({source!r}); give --mission MISSION.yaml")


def _traffic(out_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """ADS-B reports as (sorted t_sim_s, their (x, y)); none when the run wrote no traffic.csv."""
    path = out_dir / "traffic.csv"
    rows = _read_csv(path) if path.exists() else []
    data = np.array([(_number(r.get("t_sim_s")), _number(r.get("x_m")), _number(r.get("y_m"))) for r in rows])
    data = data.reshape(-1, 3)[~np.isnan(data.reshape(-1, 3)).any(axis=1)]
    data = data[np.argsort(data[:, 0])]
    return data[:, 0], data[:, 1:]


def render_replay(out_dir: Path, *, mission_path: Path | None = None, output: Path | None = None,
                  fps: int = 15, seconds: float = 12.0) -> Path:
    """Render the animation and return its path."""
    if fps < 1 or seconds <= 0:
        raise ReplayError(f"--fps must be >= 1 and --seconds > 0 (got {fps}, {seconds})")
    n_frames = max(2, int(fps * seconds))
    if n_frames > MAX_FRAMES:
        raise ReplayError(f"--fps x --seconds is {n_frames} frames; at most {MAX_FRAMES}")
    output = output or out_dir / "replay.gif"
    if output.suffix.lower() != ".gif":
        raise ReplayError(f"{output}: the animation is written as a .gif")
    tracks = _tracks(_read_csv(out_dir / "flight.csv"), out_dir / "flight.csv")
    mission = _mission(out_dir, mission_path)
    unknown = sorted(set(tracks) - {v.name for v in mission.vehicles})
    if unknown:
        raise ReplayError(f"{out_dir / 'flight.csv'}: vehicles {unknown} are not in mission {mission.name!r}; "
                          f"give the --mission that was flown")
    reports_t, reports_xy = _traffic(out_dir)
    t0 = min(float(tr[0, 0]) for tr in tracks.values())
    t_end = max(float(tr[-1, 0]) for tr in tracks.values())
    sim_offset = float(np.median(np.concatenate([tr[:, 3] - tr[:, 0] for tr in tracks.values()])))
    scene = _Scene(mission, [v.name for v in mission.vehicles if v.name in tracks], has_traffic=len(reports_t) > 0)
    frames = []
    for t in np.linspace(min(t0, 0.0), t_end, n_frames):
        ends = [int(np.searchsorted(tracks[n][:, 0], t, side="right")) for n in scene.names]
        trails = [tracks[n][:max(e, 1)] for n, e in zip(scene.names, ends)]
        t_sim = float(t) + sim_offset
        lo, hi = np.searchsorted(reports_t, [t_sim - 2.5, t_sim + 2.5])
        frames.append(scene.draw(float(t), t_sim, trails, reports_xy[lo:hi]))
    _write_gif(frames, output, fps)
    return output


class _Scene:
    """The world drawn once (the background) and the artists each frame moves."""

    def __init__(self, mission: Mission, names: list[str], *, has_traffic: bool):
        self.fig, ax = world_figure(mission, title=f"{mission.name}: replay", sweep_until_s=None)
        self.ax, self.names = ax, names
        colors = vehicle_colors(mission)
        self.trails = [ax.plot([], [], color=colors[n], lw=1.8, label=n, animated=True)[0] for n in names]
        self.heads = [ax.plot([], [], marker="o", ms=6, color=colors[n], mec="k", mew=0.6, animated=True)[0]
                      for n in names]
        self.movers = [(o, ax.fill([], [], fc="0.4", alpha=0.5, ec="0.2", animated=True,
                                   label=None if k else "moving obstacle")[0])
                       for k, o in enumerate(mission.world.moving_obstacles)]
        self.sight = ax.plot([], [], color="k", lw=1.0, animated=True,
                             label=f"sight line {names[0]}-{names[1]} (dotted: blocked)" if len(names) >= 2 else None)[0]
        self.reports = ax.plot([], [], ls="", marker="x", ms=5, color="0.15", animated=True,
                               label="ADS-B reports" if has_traffic else None)[0]
        self.clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=10, animated=True,
                             bbox={"fc": "white", "alpha": 0.8, "lw": 0})
        place_legend(self.fig, ax)
        self.static = [o.footprint for o in mission.world.static_obstacles]
        canvas = self.fig.canvas
        canvas.draw()
        self.background = canvas.copy_from_bbox(self.fig.bbox)

    def draw(self, t: float, t_sim: float, trails: list[np.ndarray], reports: np.ndarray) -> np.ndarray:
        canvas = self.fig.canvas
        canvas.restore_region(self.background)
        for line, head, trail in zip(self.trails, self.heads, trails):
            line.set_data(trail[:, 1], trail[:, 2])
            head.set_data(trail[-1:, 1], trail[-1:, 2])
        blockers = list(self.static)
        for o, patch in self.movers:
            footprint = o.footprint_at(t_sim)
            patch.set_xy(np.asarray(footprint.exterior.coords))
            blockers.append(footprint)
        self.reports.set_data(reports[:, 0], reports[:, 1])
        status = ""
        if len(trails) >= 2:
            p, q = trails[0][-1, 1:3], trails[1][-1, 1:3]
            blocked = any(LineString([p, q]).intersects(b) for b in blockers)
            self.sight.set_data([p[0], q[0]], [p[1], q[1]])
            self.sight.set_linestyle(":" if blocked else "-")
            status = f"   sight line {'blocked' if blocked else 'open'}"
        self.clock.set_text(f"t = {t:6.1f} s{status}")
        for artist in (*[p for _, p in self.movers], *self.trails, self.reports, self.sight, *self.heads, self.clock):
            self.ax.draw_artist(artist)
        return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


def _write_gif(frames: list[np.ndarray], output: Path, fps: int) -> None:
    """One 64-colour palette from the first, middle and last frames, applied to all (no dither)."""
    from PIL import Image

    output.parent.mkdir(parents=True, exist_ok=True)
    sample = np.concatenate([frames[0], frames[len(frames) // 2], frames[-1]], axis=0)
    palette = Image.fromarray(sample).quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    images[0].save(output, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
