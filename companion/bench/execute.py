"""Fly seeded scenarios x variants, headless, across processes; keep every failure replayable.

The unit of work is one scenario with all its variants: the scenario is generated once, and
its A* routes (which the generator plans anyway to prove a static route exists) are reused by
both A* variants, since routes do not depend on the variant. Every run is deterministic, so the
rows are the same for any worker count; they are returned sorted by (index, variant).

A failed run leaves ``failures/<variant>_s<seed>_i<index>/`` with the scenario YAML (variant set,
so ``companion simulate scenario.yaml`` replays it exactly), its summary.json and trajectory.png.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from companion.bench.diagnose import diagnose, hold_ticks
from companion.bench.table import run_row
from companion.planning.errors import NoPath
from companion.planning.fusion import variant_needs_route
from companion.planning.metrics import vehicle_lower_bound_s
from companion.planning.runner import simulate
from companion.scenarios import ScenarioConfig, ScenarioError, generate_scenario, with_variant, write_mission_yaml

EXAMPLE_NAME = "trajectory_example.png"


@dataclass(frozen=True)
class ScenarioTask:
    """Everything a worker needs for one scenario (picklable)."""

    seed: int
    index: int
    variants: tuple[str, ...]
    config: ScenarioConfig = field(default_factory=ScenarioConfig)
    out_dir: str | None = None  # None: write no files
    example: bool = False  # also draw this scenario's first variant as the example trajectory


def failure_dir_name(variant: str, seed: int, index: int) -> str:
    return f"{variant}_s{seed}_i{index:03d}"


def run_scenario(task: ScenarioTask) -> list[dict[str, Any]]:
    """Generate one scenario and fly every variant of the task on it; one row per variant."""
    try:
        scenario = generate_scenario(task.seed, task.index, task.config)
    except ScenarioError as exc:
        return [run_row(task.seed, task.index, f"random_s{task.seed}_i{task.index}", v, None,
                        wall_s=0.0, reason="no_scenario", error=str(exc)) for v in task.variants]
    rows = []
    bounds = {v.name: vehicle_lower_bound_s(scenario.mission, v.name) for v in scenario.mission.vehicles}
    for k, variant in enumerate(task.variants):
        started = time.perf_counter()
        result = None
        try:
            routes = scenario.routes if variant_needs_route(variant) else {}
            result = simulate(scenario.mission, variant, routes=routes, lower_bounds_s=bounds)
            summary = result.summary.summary_dict()
            facts = {"hold_ticks": hold_ticks(result.ticks), **diagnose(result.mission, result.tracks, summary)}
            row = run_row(task.seed, task.index, scenario.doc["name"], variant, summary,
                          wall_s=time.perf_counter() - started, facts=facts)
        except NoPath as exc:
            row = run_row(task.seed, task.index, scenario.doc["name"], variant, None,
                          wall_s=time.perf_counter() - started, reason="no_path", error=str(exc))
        except Exception as exc:  # a bug in one run must not sink the other 479; it is reported
            row = run_row(task.seed, task.index, scenario.doc["name"], variant, None,
                          wall_s=time.perf_counter() - started, reason="error",
                          error=f"{type(exc).__name__}: {exc}".splitlines()[0])
        rows.append(row)
        if task.out_dir is not None:
            out = Path(task.out_dir)
            if not row["success"]:
                _write_failure(out / "failures" / failure_dir_name(variant, task.seed, task.index),
                               scenario.doc, variant, row, result)
            if task.example and k == 0 and result is not None:
                _draw(out / EXAMPLE_NAME, result, f"{scenario.doc['name']} - {variant}")
    return rows


def _draw(path: Path, result: Any, title: str) -> None:
    from companion.plots import save_trajectory  # matplotlib only where a figure is drawn
    save_trajectory(path, result.mission, result.tracks, result.routes or None, title=title)


def _write_failure(folder: Path, doc: dict[str, Any], variant: str, row: dict[str, Any], result: Any) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_mission_yaml(with_variant(doc, variant), folder / "scenario.yaml")
    body = result.summary.summary_dict() if result is not None else {}
    body = {"seed": row["seed"], "index": row["index"], "variant": variant, "reason": row["reason"],
            "error": row.get("error"), **body}
    (folder / "summary.json").write_text(json.dumps(body, indent=2) + "\n", encoding="utf-8")
    if result is not None:
        _draw(folder / "trajectory.png", result,
              f"{doc['name']} - {variant}: {row['reason']} at {row.get('failure_t_s') or 0:.0f} s")


def clear_failures(out_dir: Path) -> None:
    """Remove a previous bench's failure gallery (only folders this module writes)."""
    gallery = out_dir / "failures"
    if not gallery.is_dir():
        return
    for entry in gallery.iterdir():
        if entry.is_dir() and (entry / "scenario.yaml").is_file():
            shutil.rmtree(entry)
    (gallery / "index.md").unlink(missing_ok=True)


class Progress:
    """A one-line text progress bar on a stream (a line per ~10 % when it is not a terminal)."""

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 30):
        self.total = max(total, 1)
        self.stream = stream
        self.width = width
        self.started = time.perf_counter()
        self.tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self._last_decile = -1

    def update(self, done: int, note: str = "") -> None:
        if self.stream is None:
            return
        elapsed = time.perf_counter() - self.started
        eta = elapsed / done * (self.total - done) if done else 0.0
        filled = int(self.width * done / self.total)
        line = (f"[{'#' * filled}{'.' * (self.width - filled)}] {done}/{self.total} scenarios "
                f"{elapsed:6.1f} s  eta {eta:5.0f} s  {note}")
        if self.tty:
            self.stream.write("\r" + line.ljust(100))
            if done >= self.total:
                self.stream.write("\n")
        elif done * 10 // self.total != self._last_decile or done >= self.total:
            self._last_decile = done * 10 // self.total
            self.stream.write(line + "\n")
        self.stream.flush()


def run_bench(seed: int, count: int, variants: Sequence[str], *, workers: int | None = None,
              out_dir: str | Path | None = None, config: ScenarioConfig | None = None,
              progress: TextIO | None = sys.stderr,
              on_rows: Callable[[list[dict[str, Any]]], None] | None = None) -> list[dict[str, Any]]:
    """Fly scenarios 0..count-1 of ``seed`` with every variant; rows sorted by (index, variant).

    ``workers=1`` runs in this process (tests, profiling); more uses a process pool.
    """
    workers = workers or os.cpu_count() or 1
    config = config or ScenarioConfig()
    out = None if out_dir is None else str(out_dir)
    tasks = [ScenarioTask(seed, i, tuple(variants), config, out, example=(i == 0)) for i in range(count)]
    bar = Progress(len(tasks), progress)
    rows: list[dict[str, Any]] = []
    failed = 0

    def collect(new: list[dict[str, Any]]) -> None:
        nonlocal failed
        rows.extend(new)
        failed += sum(1 for r in new if not r["success"])
        if on_rows is not None:
            on_rows(new)
        bar.update(len(rows) // max(len(variants), 1), f"{failed} failed runs")

    bar.update(0)
    if workers == 1:
        with _fewer_gc_passes():
            for task in tasks:
                collect(run_scenario(task))
    else:
        with ProcessPoolExecutor(max_workers=workers, initializer=_worker_init) as pool:
            pending = {pool.submit(run_scenario, t) for t in tasks}
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    collect(fut.result())
    order = {v: k for k, v in enumerate(variants)}
    return sorted(rows, key=lambda r: (r["index"], order[r["variant"]]))


@contextlib.contextmanager
def _fewer_gc_passes(gen0: int = 20_000):
    """A run allocates a few small objects per vehicle-tick (results, commands, snapshots) that
    die young and form no cycles, so the default young-generation threshold (700) makes the
    collector scan over and over for nothing: 5-10 % of the bench's CPU. The long-lived objects
    imported so far are frozen out of the scans, and the threshold raised, until exit."""
    saved = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(gen0, saved[1], saved[2])
    try:
        yield
    finally:
        gc.set_threshold(*saved)
        gc.unfreeze()


def _worker_init() -> None:
    """A pool worker lives for the bench only: fewer collector passes for good."""
    _fewer_gc_passes().__enter__()


def _dash(value: Any) -> str:
    return "-" if value is None else str(value)


def write_failure_index(rows: Sequence[dict[str, Any]], out_dir: Path) -> Path:
    """failures/index.md: one line per failed run, linking its replayable scenario."""
    gallery = out_dir / "failures"
    gallery.mkdir(parents=True, exist_ok=True)
    failed = [r for r in rows if not r["success"]]
    lines = ["# Failed runs", "",
             f"{len(failed)} of {len(rows)} runs failed. Replay one with "
             "`companion simulate failures/<run>/scenario.yaml`.", "",
             "| run | seed | index | variant | reason | who | obstacle hit | at (s) | min clearance (m) "
             "| min separation (m) | hold / escape ticks |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    names = sorted({k[:-len("_min_obstacle_clearance_m")] for r in rows for k in r
                    if k.endswith("_min_obstacle_clearance_m")})
    for r in failed:
        name = failure_dir_name(r["variant"], r["seed"], r["index"])
        clear = [r.get(f"{n}_min_obstacle_clearance_m") for n in names]
        clear = [c for c in clear if c is not None]
        fail_t = r.get("failure_t_s")
        sep = r.get("min_separation_m")
        png = f" ([png]({name}/trajectory.png))" if (gallery / name / "trajectory.png").exists() else ""
        hit = r.get("hit_obstacle") or "-"
        if r.get("hit_moving"):
            hit += " (moving" + (", from behind)" if r.get("hit_from_behind") else ")")
        lines.append(f"| [{name}]({name}/scenario.yaml){png} | {r['seed']} | {r['index']} | {r['variant']} | "
                     f"{r['reason']}{' - ' + r['error'] if r.get('error') else ''} | "
                     f"{r.get('failed_vehicles') or '-'} | {hit} | "
                     f"{'-' if fail_t is None else f'{fail_t:.1f}'} | "
                     f"{'-' if not clear else f'{min(clear):.1f}'} | {'-' if sep is None else f'{sep:.1f}'} | "
                     f"{_dash(r.get('hold_ticks'))} / {_dash(r.get('escape_ticks'))} |")
    path = gallery / "index.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
