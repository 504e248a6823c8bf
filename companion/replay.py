"""``companion replay OUT_DIR``: a flown run as an animated GIF.

Reads what the run wrote as it flew: ``flight.csv`` (each vehicle's pose per planner tick),
``traffic.csv`` (ADS-B reports of moving obstacles) and ``summary.json`` (which mission). The
frames are drawn in the style of the trajectory plot: true and inflated obstacles, moving
obstacles where their motion model puts them (with the reports that reached the companion as
crosses), each vehicle's trail and heading, and the sight line between the first two vehicles,
red while open and green while an obstacle blocks it.
"""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from shapely.geometry import LineString

from companion.plots import _TRACK_STYLES, trajectory_figure
from uav_model.mission import Mission, load_mission


class ReplayError(ValueError):
    """A run directory that cannot be replayed; ``str()`` names the file and the problem."""


def _read_csv(path: Path) -> list[dict[str, str]]:
    try:
        with path.open(newline="", encoding="utf-8") as f:
            return list(csv.DictReader(f))
    except FileNotFoundError:
        raise ReplayError(f"{path}: not found (replay reads the --out directory of `companion run`)") from None


def _tracks(rows: list[dict[str, str]], path: Path) -> dict[str, np.ndarray]:
    """Per vehicle, an (N, 4) array of t_mission_s, x, y, t_sim_s, in time order."""
    by: dict[str, list[tuple[float, float, float, float]]] = {}
    try:
        for r in rows:
            by.setdefault(r["vehicle"], []).append(
                (float(r["t_mission_s"]), float(r["x_m"]), float(r["y_m"]), float(r["t_sim_s"])))
    except (KeyError, ValueError) as exc:
        raise ReplayError(f"{path}: not a flight log ({exc})") from None
    if not by:
        raise ReplayError(f"{path}: no rows: nothing was flown")
    return {name: np.array(sorted(v)) for name, v in by.items()}


def _mission(out_dir: Path, mission_path: Path | None) -> Mission:
    if mission_path is not None:
        return load_mission(mission_path)
    summary = out_dir / "summary.json"
    try:
        doc = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ReplayError(f"{summary}: cannot read ({exc}); give --mission MISSION.yaml") from None
    source = doc.get("mission_file")
    if not source or not Path(source).exists():
        raise ReplayError(f"{summary}: names no mission file that exists here; give --mission MISSION.yaml")
    return load_mission(source)


def _pose_at(track: np.ndarray, t: float) -> tuple[float, float, float]:
    """(x, y, t_sim) of the last row at or before mission time t."""
    i = int(np.clip(np.searchsorted(track[:, 0], t, side="right") - 1, 0, len(track) - 1))
    return float(track[i, 1]), float(track[i, 2]), float(track[i, 3])


def render_replay(out_dir: Path, *, mission_path: Path | None = None, output: Path | None = None,
                  fps: int = 15, seconds: float = 12.0) -> Path:
    """Render the animation and return its path."""
    if fps < 1 or seconds <= 0:
        raise ReplayError(f"--fps must be >= 1 and --seconds > 0 (got {fps}, {seconds})")
    output = output or out_dir / "replay.gif"
    if output.suffix.lower() != ".gif":
        raise ReplayError(f"{output}: the animation is written as a .gif")
    mission = _mission(out_dir, mission_path)
    tracks = _tracks(_read_csv(out_dir / "flight.csv"), out_dir / "flight.csv")
    traffic = _read_csv(out_dir / "traffic.csv") if (out_dir / "traffic.csv").exists() else []
    reports_t = np.array([float(r["t_sim_s"]) for r in traffic])
    reports_xy = np.array([[float(r["x_m"]), float(r["y_m"])] for r in traffic]).reshape(-1, 2)
    t_end = max(float(tr[-1, 0]) for tr in tracks.values())
    scene = _Scene(mission, [v.name for v in mission.vehicles if v.name in tracks])
    frames = []
    for t in np.linspace(0.0, t_end, max(2, int(fps * seconds))):
        poses = [_pose_at(tracks[name], float(t)) for name in scene.names]
        trails = [tracks[name][tracks[name][:, 0] <= t] for name in scene.names]
        t_sim = poses[0][2]
        near = np.abs(reports_t - t_sim) < 2.5 if len(reports_t) else np.zeros(0, dtype=bool)
        frames.append(scene.draw(float(t), t_sim, poses, trails, reports_xy[near]))
    _write_gif(frames, output, fps)
    return output


class _Scene:
    """The trajectory plot with nothing flown, and the artists each frame moves."""

    def __init__(self, mission: Mission, names: list[str]):
        with warnings.catch_warnings():  # an empty legend until vehicles are drawn
            warnings.filterwarnings("ignore", message="No artists with labels found", category=UserWarning)
            self.fig = trajectory_figure(mission, {}, None, title=f"{mission.name}: replay")
        FigureCanvasAgg(self.fig)
        ax = self.fig.axes[0]
        self.mission, self.names = mission, names
        styles = [_TRACK_STYLES[i % len(_TRACK_STYLES)] for i in range(len(names))]
        self.trails = [ax.plot([], [], label=n, **s)[0] for n, s in zip(names, styles)]
        self.heads = [ax.plot([], [], marker="o", ms=6, color=s["color"])[0] for s in styles]
        self.sight, = ax.plot([], [], lw=1.0)
        self.movers = [(o, ax.fill([], [], fc="0.4", alpha=0.5, ec="0.2")[0]) for o in mission.world.moving_obstacles]
        self.reports, = ax.plot([], [], ls="", marker="x", ms=5, color="0.15", label="ADS-B reports")
        self.clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=10,
                             bbox={"fc": "white", "alpha": 0.8, "lw": 0})
        ax.legend(loc="lower right", fontsize=7, framealpha=0.85)
        self.static = [o.footprint for o in mission.world.static_obstacles]

    def draw(self, t: float, t_sim: float, poses, trails, reports: np.ndarray) -> np.ndarray:
        for line, head, trail, (x, y, _) in zip(self.trails, self.heads, trails, poses):
            line.set_data(trail[:, 1], trail[:, 2])
            head.set_data([x], [y])
        blockers = list(self.static)
        for o, patch in self.movers:
            footprint = o.footprint_at(t_sim)
            patch.set_xy(np.asarray(footprint.exterior.coords))
            blockers.append(footprint)
        self.reports.set_data(reports[:, 0], reports[:, 1])
        if len(poses) >= 2:
            segment = LineString([poses[0][:2], poses[1][:2]])
            blocked = any(segment.intersects(p) for p in blockers)
            self.sight.set_data([poses[0][0], poses[1][0]], [poses[0][1], poses[1][1]])
            self.sight.set_color("tab:green" if blocked else "tab:red")
        self.clock.set_text(f"t = {t:6.1f} s   sight line {'blocked' if len(poses) >= 2 and blocked else 'open'}")
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[:, :, :3].copy()


def _write_gif(frames: list[np.ndarray], output: Path, fps: int) -> None:
    from PIL import Image

    output.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=64) for f in frames]
    images[0].save(output, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0, optimize=True)
