"""The timed variant's in-flight re-plan, live: ``companion run --variant astar-bdwa-timed`` over
real UDP and MAVSDK against ``sim-bridge`` at 20x, with vehicle b held back by a position
telemetry freeze (SPEC §6's stall, ``Sitl.freeze_position``: the companion hovers b, which falls
behind its timed plan), beside the same flight without the freeze and ``companion simulate``.

Each round flies, in this order: no freeze; b frozen; and, with ``--compare-tree DIR``, b frozen
with the companion run from another checkout (e.g. one with the live re-plan removed), so the
rows of one round share the machine's load. Prints one row per flight (the companion's
summary.json: its telemetry scored as ``simulate`` scores, and its re-plans; beside it
``gcs_success``, the same scoring of the vehicles' telemetry as the GCS recorder heard it) and
the medians per kind. No pass/fail.

    python benchmarks/bench_live_replan.py [--mission M] [--rounds 3] [--freeze-after 8]
                                           [--freeze-s 20] [--compare-tree DIR] [--keep DIR]

Run it in its own network namespace (``unshare -n``) on a shared machine: it binds UDP ports.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import statistics
import tempfile
from collections.abc import Iterator
from pathlib import Path

from companion.planning.flight.headless import simulate
from companion.testing.runs import CompanionFactory
from companion.testing.stub import SitlFactory
from uav_model.mission import load_mission
from companion.bench.machine import machine_line

ROOT = Path(__file__).resolve().parents[1]
VARIANT = "astar-bdwa-timed"
COLUMNS = ("success", "gcs_success", "strict", "blocked", "a_s", "b_s", "min_sep_m", "replans_b", "tries_b",
           "first_replan_s", "worst_lag_s", "reason", "gcs_reason")


@contextlib.contextmanager
def _companion_from(tree: str | None) -> Iterator[None]:
    """Start the companion from checkout ``tree`` (None: this one): ``python -m`` puts the working
    directory first on the path, so both it and PYTHONPATH must point there."""
    if tree is None:
        yield
        return
    cwd, saved = os.getcwd(), os.environ.get("PYTHONPATH")
    os.chdir(tree)
    os.environ["PYTHONPATH"] = tree
    try:
        yield
    finally:
        os.chdir(cwd)
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved


def fly(mission: Path, work: Path, freeze_after_s: float, freeze_s: float, tree: str | None) -> dict:
    """One live flight; b's position frozen ``freeze_s`` (sim) from ``freeze_after_s`` after departure (0: none)."""
    work.mkdir(parents=True, exist_ok=True)
    stubs, companions = SitlFactory(work), CompanionFactory(work)
    try:
        stub = stubs(mission, speedup=20)
        with _companion_from(tree):
            live = companions.start(stub, "--variant", VARIANT)
        for name in ("a", "b"):
            stub.wait_for_mode(name, "OFFBOARD", timeout_s=120)
        t_depart = max(stub.mode_times(name, "OFFBOARD")[0] for name in ("a", "b"))
        window = "-"
        if freeze_s > 0:
            stub.wait_for_clock(t_depart + freeze_after_s, timeout_s=60)
            stub.freeze_position("b")
            t0 = stub.clock_s("b")
            stub.wait_for_clock(t0 + freeze_s, "b", timeout_s=60)
            stub.resume_position("b")
            window = f"{t0 - t_depart:.1f}-{stub.clock_s('b') - t_depart:.1f}"
        run = live.wait(300)
        report = stub.report()
        schedule = run.summary.get("live", {}).get("schedule", {})
        found = re.findall(r"b: behind its plan: re-planned from t = ([\d.]+) s", run.stdout)
        own = run.summary
        return dict(exit=run.exit_code, freeze=window, success=own["success"], gcs_success=report.success,
                    strict=own["success_strict"], reason=own["reason"], gcs_reason=report.reason,
                    blocked=own["los_blocked_fraction"], a_s=own["vehicles"]["a"]["flight_time_s"],
                    b_s=own["vehicles"]["b"]["flight_time_s"], min_sep_m=own["min_separation_m"],
                    replans_b=schedule.get("replans", {}).get("b"), tries_b=schedule.get("replan_tries", {}).get("b"),
                    first_replan_s=float(found[0]) if found else None, worst_lag_s=schedule.get("worst_lag_s"))
    finally:
        companions.close()
        stubs.close()


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.3f}" if value < 2 else f"{value:.1f}"
    return "-" if value is None else str(value)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "small_reference.yaml")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--freeze-after", type=float, default=8.0, metavar="S", help="sim s after departure (default 8)")
    p.add_argument("--freeze-s", type=float, default=20.0, metavar="S", help="sim s of freeze (default 20)")
    p.add_argument("--compare-tree", default=None, metavar="DIR",
                   help="also fly the frozen flight with the companion from this checkout (its PYTHONPATH)")
    p.add_argument("--keep", type=Path, default=None, metavar="DIR", help="keep every flight's files here")
    args = p.parse_args()
    print(machine_line(), flush=True)

    args.mission = args.mission.resolve()  # the compared companion runs from its own checkout
    s = simulate(load_mission(args.mission), VARIANT).summary
    print(f"headless: success {s.success}, strict {s.success_strict}, blocked {s.los_blocked_fraction:.3f}, "
          f"a {s.vehicles['a'].flight_time_s:.1f} s, b {s.vehicles['b'].flight_time_s:.1f} s "
          f"(bound {s.vehicles['b'].lower_bound_s:.1f} s)", flush=True)
    kinds = [("no freeze", 0.0, None), ("b frozen", args.freeze_s, None)]
    if args.compare_tree:
        kinds.append((f"b frozen, {Path(args.compare_tree).name}", args.freeze_s, args.compare_tree))
    rows: dict[str, list[dict]] = {k: [] for k, _, _ in kinds}
    print("round  kind                      exit freeze_s     " + "  ".join(COLUMNS), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        base = (args.keep or Path(tmp)).resolve()
        for r in range(args.rounds):
            for k, (kind, freeze_s, tree) in enumerate(kinds):
                row = fly(args.mission, base / f"round{r + 1}-kind{k + 1}", args.freeze_after, freeze_s, tree)
                rows[kind].append(row)
                print(f"{r + 1:5}  {kind:24} {row['exit']:4} {row['freeze']:10} "
                      + "  ".join(_cell(row[c]) for c in COLUMNS), flush=True)
    for kind, runs in rows.items():
        med = {c: statistics.median(float(r[c]) for r in runs)
               for c in ("blocked", "a_s", "b_s", "min_sep_m", "worst_lag_s")}
        print(f"{kind}: {sum(r['success'] for r in runs)}/{len(runs)} success "
              f"({sum(r['gcs_success'] for r in runs)} by the GCS), {sum(bool(r['strict']) for r in runs)}/{len(runs)} "
              f"strict; medians: blocked {med['blocked']:.3f}, a {med['a_s']:.1f} s, b {med['b_s']:.1f} s, "
              f"min separation {med['min_sep_m']:.1f} m, worst lag {med['worst_lag_s']:.1f} s; "
              f"re-plans of b {[r['replans_b'] for r in runs]}")


if __name__ == "__main__":
    main()
