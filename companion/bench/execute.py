"""Fly seeded scenarios x variants (x score weights) on any executor; keep every failure replayable.

The unit of work is one scenario with all its runs: the scenario is generated once, and its A*
routes (which the generator plans anyway to prove a static route exists) are reused by every A*
run, since routes depend on neither the variant nor the score weights. Every run is
deterministic, so the rows are the same for any executor and worker count; they are returned
sorted by (index, variant, weights).

Workers return what they made instead of writing it: a failed run's files (the scenario YAML with
its variant and weights set, so ``companion simulate scenario.yaml`` replays it exactly, its
summary.json and trajectory.png) travel back with the rows, and this process writes them under
``failures/<run>/``. So the gallery is complete even when the workers are other machines.
"""

from __future__ import annotations

import io
import json
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from companion.bench.diagnose import diagnose, no_rollout_ticks
from companion.bench.orca import BASELINES, ROUTE_VARIANT, simulate_orca
from companion.bench.executors import ExecutorError, ExecutorSpec, Pool, open_pool
from companion.bench.table import certificate_columns, run_row
from companion.bench.weights import COLUMNS as WEIGHT_COLUMNS
from companion.bench.weights import Weights
from companion.planning.errors import NoPath
from companion.planning.timed_route import TimedRoute
from companion.planning.variants import variant_needs_route
from companion.planning.metrics import FailureReason, vehicle_lower_bound_s
from companion.planning.flight.forecast import first_forecast, mission_certificates
from companion.planning.flight.replay import forecast_key
from companion.planning.flight.headless import simulate
from companion.scenarios import (ScenarioConfig, ScenarioError, generate_scenario, mission_yaml_text,
                                 with_variant)

EXAMPLE_NAME = "trajectory_example.png"


@dataclass(frozen=True)
class ScenarioTask:
    """Everything a worker needs for one scenario (picklable)."""

    seed: int
    index: int
    variants: tuple[str, ...]
    config: ScenarioConfig = field(default_factory=ScenarioConfig)
    artefacts: bool = False  # return the failure gallery's files (and the example) with the rows
    example: bool = False  # also draw this scenario's first run as the example trajectory
    weight_sets: tuple[Weights | None, ...] = (None,)  # None: the mission's weights
    certificate: bool = True  # work out each run's occlusion certificate (its cert_* columns)

    def runs(self) -> Iterator[tuple[str, Weights | None]]:
        for variant in self.variants:
            for weights in self.weight_sets:
                yield variant, weights


@dataclass(frozen=True)
class ScenarioOutcome:
    """A worker's answer: one row per run, and the files to write (path relative to --out)."""

    rows: list[dict[str, Any]]
    files: tuple[tuple[str, bytes], ...] = ()


def failure_dir_name(variant: str, seed: int, index: int, weights: Weights | None = None) -> str:
    tag = "" if weights is None else f"_{weights.tag}"
    return f"{variant}{tag}_s{seed}_i{index:03d}"


def run_scenario(task: ScenarioTask) -> ScenarioOutcome:
    """Generate one scenario and fly every run of the task on it; one row per run."""
    try:
        scenario = generate_scenario(task.seed, task.index, task.config)
    except ScenarioError as exc:
        return ScenarioOutcome([_weighted(run_row(task.seed, task.index, f"random_s{task.seed}_i{task.index}", v,
                                                  None, wall_s=0.0, reason=FailureReason.NO_SCENARIO, error=str(exc)), w)
                                for v, w in task.runs()])
    rows, files = [], []
    judged = _Certificates(scenario, task.certificate)
    bounds = {v.name: vehicle_lower_bound_s(scenario.mission, v.name) for v in scenario.mission.vehicles}
    for k, (variant, weights) in enumerate(task.runs()):
        mission = scenario.mission if weights is None else weights.apply(scenario.mission)
        routes = scenario.routes if variant in BASELINES or variant_needs_route(variant) else {}
        flies = ROUTE_VARIANT if variant in BASELINES else variant  # ORCA follows that variant's routes
        flown = mission.with_variant(flies)
        first, cert = judged.of(flown, (forecast_key(flown), weights))
        row, result = _fly(task, scenario.doc["name"], mission, variant, routes, bounds, first)
        rows.append(_weighted({**row, **cert}, weights))
        if not task.artefacts:
            continue
        if not row["success"]:
            doc = with_variant(scenario.doc if weights is None else weights.apply_doc(scenario.doc),
                               ROUTE_VARIANT if variant in BASELINES else variant)
            files += _failure_files(failure_dir_name(variant, task.seed, task.index, weights), doc, rows[-1], result)
        if task.example and k == 0 and result is not None:
            files.append((EXAMPLE_NAME, _png(result, f"{scenario.doc['name']} - {variant}")))
    return ScenarioOutcome(rows, tuple(files))


class _Certificates:
    """Each run's occlusion certificate, of the forecast its own variant (and weights) fly: the
    first vehicle flown alone once per forecast (variants that fly it alike share it:
    :func:`forecast_key`), shared with the timed run that plans against it, and one certificate
    per distinct forecast."""

    def __init__(self, scenario: Any, wanted: bool):
        self.scenario, self.wanted = scenario, wanted
        self._forecasts: dict[Any, TimedRoute | None] = {}
        self._columns: dict[bytes, dict[str, Any]] = {}

    def of(self, mission: Any, key: Any) -> tuple[TimedRoute | None, dict[str, Any]]:
        """(the first vehicle's forecast as ``mission`` flies it, or None; its ``cert_*`` columns);
        ``key`` names the forecast among the scenario's runs (its :func:`forecast_key` and weights)."""
        if not self.wanted or len(mission.vehicles) < 2:
            return None, {}
        if key not in self._forecasts:
            self._forecasts[key] = self._forecast(mission)
        first = self._forecasts[key]
        if first is None:
            return None, {}
        tag = first.t_s.tobytes() + first.xy_enu_m.tobytes()
        if tag not in self._columns:
            self._columns[tag] = self._judge(mission, first)
        return first, self._columns[tag]

    def _forecast(self, mission: Any) -> TimedRoute | None:
        try:
            return first_forecast(mission, self.scenario.routes)
        except Exception as exc:  # a certificate bug must not sink the scenario's flights
            self._report(exc)
            return None

    def _judge(self, mission: Any, first: TimedRoute) -> dict[str, Any]:
        try:
            certificates = mission_certificates(mission, self.scenario.routes, first=first)
            return certificate_columns(certificates[0] if certificates else None,
                                       certificates if mission.assigned_pairs is not None else ())
        except Exception as exc:  # a certificate bug must not sink the scenario's flights
            self._report(exc)
            return {}

    def _report(self, exc: Exception) -> None:
        print(f"certificate of {self.scenario.doc['name']} failed: {type(exc).__name__}: {exc}", file=sys.stderr)


def _weighted(row: dict[str, Any], weights: Weights | None) -> dict[str, Any]:
    return row if weights is None else {**row, **weights.columns()}


def _fly(task: ScenarioTask, name: str, mission: Any, variant: str, routes: dict,
         bounds: dict, first: TimedRoute | None = None) -> tuple[dict[str, Any], Any]:
    """One run as a row (and its result, None when it did not fly); ``first``: the first
    vehicle's forecast as this run's variant flies it, when already flown."""
    started = time.perf_counter()
    try:
        if variant in BASELINES:
            result = simulate_orca(mission, routes=routes, lower_bounds_s=bounds)
        else:
            result = simulate(mission, variant, routes=routes, lower_bounds_s=bounds, first=first)
        summary = result.summary.summary_dict()
        facts = {"no_rollout_ticks": no_rollout_ticks(result.ticks), **diagnose(result.mission, result.tracks, summary)}
        return run_row(task.seed, task.index, name, variant, summary,
                       wall_s=time.perf_counter() - started, facts=facts), result
    except NoPath as exc:
        return run_row(task.seed, task.index, name, variant, None, wall_s=time.perf_counter() - started,
                       reason=FailureReason.NO_PATH, error=str(exc)), None
    except Exception as exc:  # a bug in one run must not sink the other 479; it is reported
        return run_row(task.seed, task.index, name, variant, None, wall_s=time.perf_counter() - started,
                       reason=FailureReason.ERROR, error=f"{type(exc).__name__}: {exc}".splitlines()[0]), None


def _png(result: Any, title: str) -> bytes:
    from companion.plots import trajectory_figure  # matplotlib only where a figure is drawn
    buffer = io.BytesIO()
    trajectory_figure(result.mission, result.tracks, result.routes or None, title=title).savefig(buffer, format="png")
    return buffer.getvalue()


def _failure_files(name: str, doc: dict[str, Any], row: dict[str, Any], result: Any) -> list[tuple[str, bytes]]:
    folder = f"failures/{name}"
    body = result.summary.summary_dict() if result is not None else {}
    body = {"seed": row["seed"], "index": row["index"], "variant": row["variant"], "reason": row["reason"],
            "error": row.get("error"), **{k: row[k] for k in WEIGHT_COLUMNS if k in row},
            **body}
    files = [(f"{folder}/scenario.yaml", mission_yaml_text(doc).encode()),
             (f"{folder}/summary.json", (json.dumps(body, indent=2) + "\n").encode())]
    if result is not None:
        files.append((f"{folder}/trajectory.png", _png(
            result, f"{doc['name']} - {row['variant']}: {row['reason']} at {row.get('failure_t_s') or 0:.0f} s")))
    return files


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
              pool: Pool | None = None, out_dir: str | Path | None = None, config: ScenarioConfig | None = None,
              progress: TextIO | None = sys.stderr, weight_sets: Sequence[Weights | None] = (None,),
              on_rows: Callable[[list[dict[str, Any]]], None] | None = None,
              certificate: bool = True) -> list[dict[str, Any]]:
    """Fly scenarios 0..count-1 of ``seed`` with every variant (x weight set); rows sorted by
    (index, variant, weight set), in the order given.

    Runs on ``pool`` (see :func:`companion.bench.executors.open_pool`), else on a local pool of
    ``workers`` processes (1: in this process). Raises :class:`ExecutorError` when a worker fails.
    """
    config = config or ScenarioConfig()
    weight_sets = tuple(weight_sets)
    artefacts = out_dir is not None
    tasks = [ScenarioTask(seed, i, tuple(variants), config, artefacts, example=(i == 0), weight_sets=weight_sets,
                          certificate=certificate) for i in range(count)]
    bar = Progress(len(tasks), progress)
    rows: list[dict[str, Any]] = []
    failed = 0

    def collect(outcome: ScenarioOutcome) -> None:
        nonlocal failed
        for name, content in outcome.files:
            path = Path(out_dir) / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(content)
        rows.extend(outcome.rows)
        failed += sum(1 for r in outcome.rows if not r["success"])
        if on_rows is not None:
            on_rows(outcome.rows)
        bar.update(len(rows) // max(len(variants) * len(weight_sets), 1), f"{failed} failed runs")

    bar.update(0)
    if pool is not None:
        _run_tasks(pool, tasks, collect)
    else:
        with open_pool(ExecutorSpec(workers=workers)) as own:
            _run_tasks(own, tasks, collect)
    order = {v: k for k, v in enumerate(variants)}
    w_order = {w: k for k, w in enumerate(weight_sets)}
    return sorted(rows, key=lambda r: (r["index"], order[r["variant"]], w_order[Weights.from_row(r)]))


def _run_tasks(pool: Pool, tasks: Sequence[ScenarioTask], collect: Callable[[ScenarioOutcome], None]) -> None:
    """Keep ``pool.window`` tasks submitted, collect each outcome as it finishes."""
    queue = iter(tasks)
    pending: set[Future] = set()

    def top_up() -> None:
        for task in queue:
            pending.add(pool.executor.submit(run_scenario, task))
            if len(pending) >= pool.window:
                return

    try:
        top_up()
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                collect(_outcome(future))
            top_up()
    finally:
        for future in pending:
            future.cancel()


def _outcome(future: Future) -> ScenarioOutcome:
    try:
        return future.result()
    except Exception as exc:  # every run's own errors are rows; this is the worker or its link
        text = str(exc).strip().splitlines()
        raise ExecutorError(f"a worker failed: {type(exc).__name__}{': ' + text[0] if text else ''}") from None


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
             "| min separation (m) | no-rollout / escape ticks |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    names = sorted({k[:-len("_min_obstacle_clearance_m")] for r in rows for k in r
                    if k.endswith("_min_obstacle_clearance_m")})
    for r in failed:
        name = failure_dir_name(r["variant"], r["seed"], r["index"], Weights.from_row(r))
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
                     f"{_dash(r.get('no_rollout_ticks'))} / {_dash(r.get('escape_ticks'))} |")
    path = gallery / "index.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
