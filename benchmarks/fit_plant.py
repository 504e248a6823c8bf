"""Replay PX4 SITL's offboard command segments through the plants and compare them with PX4.

    python benchmarks/fit_plant.py [--px4-dir DIR] [--figure docs/img/plant_fit.png]

The traces are ../shared/px4-sih/characterisation/px4_sih_{1x,4x}.csv.gz (PX4 SITL, SIH physics;
see that folder's README), the command times come from the step logs beside them. The
multicopter plant was fitted on 1x; 4x is held out. Each segment is replayed from PX4's own
state at the start of the turn, through all four segments in sequence, at the stub's 20 ms step.

Per segment it prints PX4 beside the plant: the steady ground speed and heading rate (mean
over the segment's second half), ATTITUDE's body yawspeed, and the time to 90 % of the step
(speed for the speed changes, heading rate for the yaw in place). tests/model/test_plant_fit.py
asserts the turn and over-speed columns from these same functions.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uav_model.plant import KinematicState, MulticopterLimits, Plant, VehicleLimits, VelocityCommand, VelocityFrame, step_for
from uav_model.plant.multicopter import attitude

REPO = Path(__file__).resolve().parents[1]
STUB_DT_S = 0.02
# The old stub on the reference mission: 10 m/s, v/r = 10/30 rad/s, 8 m/s^2.
UNICYCLE_LIMITS = VehicleLimits(max_speed_m_s=10.0, max_yaw_rate_rad_s=10.0 / 30.0, max_accel_m_s2=8.0)


def px4_sih_dir(start: Path = REPO) -> Path | None:
    """``<repo>/../shared/px4-sih``, looked for from the repo root upward (worktrees sit deeper)."""
    for base in (start, *start.parents):
        candidate = base.parent / "shared" / "px4-sih"
        if candidate.is_dir():
            return candidate
    return None


@dataclass(frozen=True)
class Segment:
    name: str
    t0_s: float  # PX4 boot time the command starts
    t1_s: float
    forward_m_s: float  # BODY_NED x
    yawspeed_rad_s: float  # NED, clockwise-positive


@dataclass(frozen=True)
class Series:
    """A flown response: LOCAL_POSITION_NED-like samples with the attitude at the same times."""

    t_s: np.ndarray
    vn_m_s: np.ndarray
    ve_m_s: np.ndarray
    yaw_rad: np.ndarray  # unwrapped
    body_yawspeed_rad_s: np.ndarray

    @property
    def speed_m_s(self) -> np.ndarray:
        return np.hypot(self.vn_m_s, self.ve_m_s)


@dataclass(frozen=True)
class SegmentMetrics:
    speed_m_s: float
    heading_rate_deg_s: float
    body_yawspeed_deg_s: float
    t90_s: float


_STEP_LINES = {  # characterise.py's step log: where each offboard segment starts and ends
    "turn": "begin forward", "yaw": "yaw in place", "over-speed": "forward 15",
    "stop": "ground speed now", "end": "STOP setpoints (offboard",
}
_COMMANDS = {"turn": (10.0, math.radians(-19.1)), "yaw": (0.0, math.radians(90.0)),
             "over-speed": (15.0, 0.0), "stop": (0.0, 0.0)}


def segments_from_log(path: Path) -> list[Segment]:
    """The four offboard segments of a characterise.py log, in PX4 boot time."""
    starts: dict[str, float] = {}
    for line in path.read_text().splitlines():
        m = re.match(r"\[w\s*[\d.]+ s\s*([\d.]+)\] (.*)", line)
        if m is None:
            continue
        for name, prefix in _STEP_LINES.items():
            if m.group(2).startswith(prefix) and name not in starts:
                starts[name] = float(m.group(1))
    names = list(_STEP_LINES)
    return [Segment(n, starts[n], starts[names[i + 1]], *_COMMANDS[n]) for i, n in enumerate(names[:-1])]


def load_trace(path: Path) -> Series:
    """PX4's LOCAL_POSITION_NED samples, with ATTITUDE's yaw and yawspeed interpolated to them."""
    pos, att = [], []
    with gzip.open(path, "rt") as f:
        for row in csv.DictReader(f):
            if row["kind"] not in ("pos", "att"):  # heartbeats carry no boot time
                continue
            t = float(row["time_boot_ms"]) / 1000.0
            if row["kind"] == "pos":
                pos.append((t, float(row["d"]), float(row["e"])))
            else:
                att.append((t, float(row["c"]), float(row["d"])))
    p, a = np.asarray(pos), np.asarray(att)
    yaw = np.interp(p[:, 0], a[:, 0], np.unwrap(a[:, 1]))
    return Series(p[:, 0], p[:, 1], p[:, 2], yaw, np.interp(p[:, 0], a[:, 0], a[:, 2]))


def replay(segments: list[Segment], plant: Plant, start: Series, limits=None, dt_s: float = STUB_DT_S) -> Series:
    """Fly ``segments`` on ``plant`` from PX4's state at the first segment's start."""
    limits = limits or (MulticopterLimits() if plant is Plant.MULTICOPTER else UNICYCLE_LIMITS)
    step = step_for(plant)
    i = int(np.searchsorted(start.t_s, segments[0].t0_s))
    state = KinematicState(0.0, 0.0, -20.0, float(start.vn_m_s[i]), float(start.ve_m_s[i]),
                           yaw_rad=float(start.yaw_rad[i]))
    t = segments[0].t0_s
    rows = []
    for seg in segments:
        command = VelocityCommand(VelocityFrame.BODY_NED, seg.forward_m_s, 0.0, 0.0, seg.yawspeed_rad_s)
        for _ in range(int(round((seg.t1_s - t) / dt_s))):
            state = step(state, command, limits, dt_s)
            t += dt_s
            body_r = attitude(state)[2] if plant is Plant.MULTICOPTER else state.yawspeed_rad_s
            rows.append((t, state.vn_m_s, state.ve_m_s, state.yaw_rad, body_r))
    r = np.asarray(rows)
    return Series(r[:, 0], r[:, 1], r[:, 2], np.unwrap(r[:, 3]), r[:, 4])


def segment_metrics(series: Series, seg: Segment) -> SegmentMetrics:
    """Steady values over the segment's second half, and the time to 90 % of the step."""
    m = (series.t_s >= seg.t0_s) & (series.t_s < seg.t1_s)
    t, speed, yaw = series.t_s[m], series.speed_m_s[m], series.yaw_rad[m]
    late = t >= 0.5 * (seg.t0_s + seg.t1_s)
    speed_ss = float(speed[late].mean())
    rate_ss = float(np.polyfit(t[late], yaw[late], 1)[0])
    if seg.name == "yaw":  # the heading rate's rise, from the yaw angle (smoothed over 5 samples)
        rate = np.convolve(np.gradient(yaw, t), np.ones(5) / 5.0, "same")
        reached = np.flatnonzero(rate >= 0.9 * rate_ss)
    else:  # the ground speed's: up for the turn and the over-speed, down for the stop
        target = speed[0] + 0.9 * (speed_ss - speed[0])
        reached = np.flatnonzero(speed >= target if speed_ss > speed[0] else speed <= target)
    t90 = float(t[reached[0]] - seg.t0_s) if reached.size else math.nan
    return SegmentMetrics(speed_ss, math.degrees(rate_ss),
                          math.degrees(float(series.body_yawspeed_rad_s[m][late].mean())), t90)


def compare(trace: Path, log: Path, plant: Plant = Plant.MULTICOPTER, limits=None, dt_s: float = STUB_DT_S):
    """[(segment, PX4 metrics, plant metrics)], plus both series."""
    segments = segments_from_log(log)
    px4 = load_trace(trace)
    flown = replay(segments, plant, px4, limits, dt_s)
    return [(s, segment_metrics(px4, s), segment_metrics(flown, s)) for s in segments], px4, flown


def _row(label: str, px4: float, plant: float, unit: str) -> str:
    err = f"{(plant / px4 - 1.0) * 100.0:+6.1f} %" if abs(px4) >= 1.0 else "     -"  # no % of ~0
    return f"  {label:<22} {px4:8.2f} {plant:8.2f} {unit:<6} {err}"


def print_table(title: str, rows) -> None:
    print(f"\n{title}\n  {'':<22} {'PX4':>8} {'plant':>8}")
    for seg, a, b in rows:
        print(f" {seg.name} ({seg.t1_s - seg.t0_s:.1f} s: {seg.forward_m_s:g} m/s, "
              f"{math.degrees(seg.yawspeed_rad_s):+.1f} deg/s)")
        print(_row("speed", a.speed_m_s, b.speed_m_s, "m/s"))
        print(_row("heading rate", a.heading_rate_deg_s, b.heading_rate_deg_s, "deg/s"))
        print(_row("ATTITUDE yawspeed", a.body_yawspeed_deg_s, b.body_yawspeed_deg_s, "deg/s"))
        print(_row("time to 90 %", a.t90_s, b.t90_s, "s"))


def figure(path: Path, px4: Series, multi: Series, uni: Series, segments: list[Segment]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    by = {s.name: s for s in segments}
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), constrained_layout=True)
    panels = [(axes[0, 0], "turn", "speed", "turn (10 m/s, -19.1 deg/s): ground speed"),
              (axes[0, 1], "turn", "rate", "turn: ATTITUDE yawspeed (body)"),
              (axes[1, 0], "over-speed", "speed", "over-speed (15 m/s commanded): ground speed"),
              (axes[1, 1], "yaw", "rate", "yaw in place (90 deg/s): ATTITUDE yawspeed")]
    for ax, name, what, title in panels:
        seg = by[name]
        for series, label, style in ((px4, "PX4 SITL (SIH)", "k-"), (multi, "stub: multicopter", "C0-"),
                                     (uni, "stub: unicycle (old)", "C3--")):
            m = (series.t_s >= seg.t0_s - 0.5) & (series.t_s < seg.t1_s)
            y = series.speed_m_s[m] if what == "speed" else np.degrees(series.body_yawspeed_rad_s[m])
            ax.plot(series.t_s[m] - seg.t0_s, y, style, lw=1.4, label=label)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("s since the command")
        ax.set_ylabel("m/s" if what == "speed" else "deg/s")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="lower right", fontsize=9)
    fig.suptitle("PX4 SITL against the stub's plants, same commands (px4_sih_1x)", fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"\nwrote {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--px4-dir", type=Path, default=None, help="default: <repo>/../shared/px4-sih")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "img" / "plant_fit.png")
    args = ap.parse_args(argv)
    base = args.px4_dir or px4_sih_dir()
    if base is None:
        raise SystemExit("fit_plant: no ../shared/px4-sih next to the repo; pass --px4-dir")
    d = base / "characterisation"
    for run, role in (("1x", "fit"), ("4x", "held out")):
        rows, _, _ = compare(d / f"px4_sih_{run}.csv.gz", d / f"px4_sih_{run}.log")
        print_table(f"px4_sih_{run} ({role}): PX4 against the multicopter plant, 20 ms steps", rows)
    rows, _, _ = compare(d / "px4_sih_1x.csv.gz", d / "px4_sih_1x.log", dt_s=0.5)
    print_table("px4_sih_1x: the multicopter plant at the headless runner's 0.5 s step", rows)
    rows, px4, uni = compare(d / "px4_sih_1x.csv.gz", d / "px4_sih_1x.log", Plant.UNICYCLE)
    print_table("px4_sih_1x: PX4 against the unicycle (the old stub)", rows)
    _, _, multi = compare(d / "px4_sih_1x.csv.gz", d / "px4_sih_1x.log")
    figure(args.figure, px4, multi, uni, segments_from_log(d / "px4_sih_1x.log"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
