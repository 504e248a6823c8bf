"""``companion bench`` and ``companion sweep weights``: the summary they write is exactly what
runs.csv says, failures are replayable, and the result depends on neither the worker count nor
the executor (a real Dask cluster on loopback).

The flights are real headless runs of the real planner, on a small world (a 1 km square,
~100 s flights) so that the whole file takes seconds.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import yaml

from companion.bench import aggregate, read_runs_csv
from companion.bench import sweep
from companion.cli.bench import run
from companion.bench.diagnose import diagnose
from companion.bench.execute import failure_dir_name, run_bench
from companion.bench.machine import cpu_model
from companion.bench.table import format_table, write_runs_csv
from companion.bench.weights import Weights
from companion.cli import main as cli_main
from uav_model.mission import load_mission, parse_mission
from companion.planning.metrics import Track
from companion.planning.flight.headless import simulate
from companion.scenarios import ScenarioConfig

try:
    import distributed
except ImportError:  # the `dask` extra: .ci/run installs it, the README's install does not
    distributed = None
needs_dask = pytest.mark.skipif(distributed is None, reason="needs the dask extra: pip install -e '.[dask]'")

SMALL = {"side_m": 1000.0, "static_count": 2, "static_circumradius_m": [40.0, 90.0],
         "moving_count": 1, "moving_radius_m": [20.0, 30.0], "moving_path_m": [150.0, 300.0],
         "moving_speed_m_s": [2.0, 4.0], "station_clearance_m": 100.0}


@pytest.fixture(scope="module")
def small_bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    cfg = out / "small.yaml"
    cfg.write_text(yaml.safe_dump(SMALL))
    code = run(["--scenarios", "2", "--seed", "7", "--variants", "astar-bdwa,bdwa", "--workers", "1",
                "--out", str(out), "--scenario-config", str(cfg), "--quiet"])
    return out, code


def test_summary_json_is_the_aggregate_of_runs_csv(small_bench):
    out, code = small_bench
    rows = read_runs_csv(out / "runs.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert [(r["index"], r["variant"]) for r in rows] == [(0, "astar-bdwa"), (0, "bdwa"),
                                                          (1, "astar-bdwa"), (1, "bdwa")]
    assert aggregate(rows) == summary
    for variant, s in summary.items():  # and the headline numbers by hand
        mine = [r for r in rows if r["variant"] == variant]
        assert s["runs"] == 2
        assert s["successes"] == sum(r["success"] for r in mine)
        assert s["collisions"] == sum(r["reason"] == "collision" for r in mine)
        assert sum(s["reasons"].values()) == s["runs"] - s["successes"]
    unsafe = sum(s["unsafe"] + s["reasons"].get("error", 0) for s in summary.values())
    assert code == (1 if unsafe else 0)


def test_bench_writes_every_artefact(small_bench):
    out, _ = small_bench
    for name in ("runs.csv", "summary.json", "table.md", "meta.json", "violin.png", "lines.png",
                 "trajectory_example.png", "failures/index.md"):
        assert (out / name).stat().st_size > 0, name
    meta = json.loads((out / "meta.json").read_text())
    assert meta["command"].startswith("companion bench --scenarios 2 --seed 7 --variants astar-bdwa,bdwa")
    assert meta["scenario_config"]["side_m"] == 1000.0
    assert meta["cpu"] == cpu_model()  # a wall time means nothing without the CPU that made it
    rows = read_runs_csv(out / "runs.csv")
    index = (out / "failures" / "index.md").read_text()
    for r in rows:  # a gallery entry for exactly the failed runs
        entry = out / "failures" / failure_dir_name(r["variant"], r["seed"], r["index"])
        assert entry.is_dir() == (not r["success"])
        # As a link: "bdwa_s7_i001" is also inside "astar-bdwa_s7_i001".
        assert (f'[{failure_dir_name(r["variant"], r["seed"], r["index"])}]' in index) == (not r["success"])


def test_a_failed_run_replays_from_its_gallery_yaml(tmp_path):
    # A 20 s time limit makes every run a timeout: the gallery must hold each, replayable.
    cfg = tmp_path / "short.yaml"
    cfg.write_text(yaml.safe_dump({**SMALL, "time_limit_s": 20.0}))
    out = tmp_path / "out"
    assert run(["--scenarios", "1", "--seed", "3", "--variants", "astar-bdwa,dwa", "--workers", "1",
                "--out", str(out), "--scenario-config", str(cfg), "--quiet"]) == 0
    rows = read_runs_csv(out / "runs.csv")
    assert [r["reason"] for r in rows] == ["timeout", "timeout"]
    for r in rows:
        entry = out / "failures" / failure_dir_name(r["variant"], 3, 0)
        assert (entry / "trajectory.png").stat().st_size > 0
        mission = load_mission(entry / "scenario.yaml")
        assert mission.planner.variant == r["variant"]
        replay = simulate(mission).summary.summary_dict()
        assert replay["reason"] == "timeout"
        assert replay["vehicles"]["a"]["path_length_m"] == pytest.approx(r["a_path_length_m"])
        assert replay["min_separation_m"] == pytest.approx(r["min_separation_m"])
    # A second bench into the same directory leaves no stale gallery entries behind.
    assert run(["--scenarios", "1", "--seed", "3", "--variants", "dwa", "--workers", "1",
                "--out", str(out), "--scenario-config", str(cfg), "--quiet"]) == 0
    assert sorted(p.name for p in (out / "failures").iterdir()) == ["dwa_s3_i000", "index.md"]


def test_rows_do_not_depend_on_the_worker_count():
    cfg = ScenarioConfig.from_mapping(SMALL)
    alone = run_bench(5, 2, ["dwa"], workers=1, config=cfg, progress=None)
    pooled = run_bench(5, 2, ["dwa"], workers=2, config=cfg, progress=None)
    strip = [{k: v for k, v in r.items() if k not in ("wall_s", "planner_ms_per_tick")} for r in alone]
    assert strip == [{k: v for k, v in r.items() if k not in ("wall_s", "planner_ms_per_tick")} for r in pooled]


def _collector_settings() -> tuple:
    import gc
    return gc.get_threshold(), gc.get_freeze_count()


def test_a_pool_worker_keeps_fewer_collector_passes():
    """The local pool's workers run with the raised young-generation threshold and the objects
    of their start frozen, from their first task on (an initialiser that entered the context
    manager and dropped it had undone both before any task ran)."""
    from concurrent.futures import ProcessPoolExecutor
    from companion.bench.executors import worker_init
    with ProcessPoolExecutor(max_workers=1, initializer=worker_init) as pool:
        (gen0, _, _), frozen = pool.submit(_collector_settings).result()
    assert gen0 == 20_000 and frozen > 0

def _timeless(path):
    return [{k: v for k, v in r.items() if k not in ("wall_s", "planner_ms_per_tick")} for r in read_runs_csv(path)]


@pytest.fixture
def dask_cluster():
    """A real Dask cluster on loopback: a TCP scheduler and two single-thread workers in this process."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        yield cluster.scheduler_address


@needs_dask
def test_a_dask_cluster_gives_the_local_runs_csv(small_bench, dask_cluster, tmp_path):
    local_out, _ = small_bench
    out = tmp_path / "dask"
    run(["--scenarios", "2", "--seed", "7", "--variants", "astar-bdwa,bdwa", "--executor", "dask",
         "--scheduler", dask_cluster, "--out", str(out), "--scenario-config", str(local_out / "small.yaml"), "--quiet"])
    assert _timeless(out / "runs.csv") == _timeless(local_out / "runs.csv")
    assert (out / "trajectory_example.png").stat().st_size > 0  # drawn on a worker, written here
    assert json.loads((out / "meta.json").read_text())["command"].endswith(
        f"--executor dask --scheduler {dask_cluster} --out {out}")


def _row(index, variant, success, reason=None, a=500.0, b=600.0):
    return {"seed": 1, "index": index, "scenario": f"s{index}", "variant": variant, "success": success,
            "success_strict": success and index == 0, "reason": reason, "planner_ms_per_tick": 1.0,
            "wall_s": 2.0, "a_arrived": success, "a_flight_time_s": a, "a_ratio": a / 400.0,
            "b_arrived": success, "b_flight_time_s": b, "b_ratio": b / 400.0}


def test_aggregate_counts_and_times_over_successes_only(tmp_path):
    rows = [_row(0, "x", True, a=500.0), _row(1, "x", True, a=700.0), _row(2, "x", False, "collision", a=9.0),
            _row(0, "y", True, a=550.0), _row(1, "y", False, "timeout"), _row(2, "y", False, "timeout")]
    s = aggregate(rows)
    assert list(s) == ["x", "y"]
    assert (s["x"]["successes"], s["x"]["strict_successes"], s["x"]["collisions"]) == (2, 1, 1)
    assert s["x"]["success_rate"] == pytest.approx(2 / 3, abs=1e-4)
    assert s["x"]["flight_time_s"]["a"]["mean"] == 600.0  # the 9 s collision run is not a flight time
    assert s["y"]["reasons"] == {"timeout": 2}
    assert s["x"]["common_scenarios"] == 1  # only scenario 0 succeeded with both
    assert s["x"]["flight_time_common_s"]["a"]["mean"] == 500.0
    assert s["x"]["ratio_to_bound"]["b"]["median"] == 1.5
    assert "collision 1" in format_table(s)
    write_runs_csv(rows, tmp_path / "runs.csv")
    assert aggregate(read_runs_csv(tmp_path / "runs.csv")) == s


def test_bad_arguments_are_one_line_errors(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        run(["--variants", "astar-bdwa,warp"])
    assert exc.value.code == 2
    assert "unknown variant(s) warp" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("side: 5\n")
    assert run(["--scenarios", "1", "--scenario-config", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("companion bench: ") and "unknown scenario key(s) side" in err
    assert len(err.strip().splitlines()) == 1


@needs_dask
@pytest.mark.timeout(60)  # the connect timeout bounds it: a hang fails here
@pytest.mark.parametrize("argv, message", [
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "1"],
     "cannot use tcp://127.0.0.1:1: Timed out trying to connect"),
    (["--executor", "dask", "--scheduler", "127.0.0.1"], "--scheduler: not a scheduler address"),
    (["--scheduler", "tcp://127.0.0.1:8786"], "--scheduler needs --executor dask"),
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"], "--workers sizes a local cluster"),
])
def test_bad_executor_options_are_one_line_errors(capsys, tmp_path, argv, message):
    assert run(["--scenarios", "1", "--out", str(tmp_path / "o"), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("companion bench: ") and message in err, err
    assert len(err.strip().splitlines()) == 1


def test_opposite_sight_pairs_are_scored_per_run(tmp_path):
    cfg = tmp_path / "small.yaml"
    cfg.write_text(yaml.safe_dump(SMALL))
    out = tmp_path / "out"
    code = run(["--scenarios", "1", "--seed", "7", "--variants", "astar-bdwa", "--workers", "1", "--vehicles", "4",
                "--sight-pairs", "opposite", "--no-certificate", "--out", str(out), "--scenario-config", str(cfg),
                "--quiet"])
    rows = read_runs_csv(out / "runs.csv")
    assert code in (0, 1) and len(rows) == 1 and rows[0]["reason"] != "error"
    r = rows[0]
    assert r["sight_pairs"] == 2  # a-c and b-d, both scored
    assert r["sight_pairs_occluded"] == sum(bool(r[f"{p}_crossing_occluded"]) for p in ("a-c", "b-d"))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["astar-bdwa"]["sight_pairs"] == {"scored": 2, "occluded": r["sight_pairs_occluded"]}
    assert f"blocked at closest approach in {r['sight_pairs_occluded']} of 2 scored pairs" in format_table(summary)
    meta = json.loads((out / "meta.json").read_text())
    assert "--vehicles 4 --sight-pairs opposite" in meta["command"] and meta["scenario_config"]["sight_pairs"] == "opposite"


def test_a_failed_run_with_sight_pairs_replays_them(tmp_path):
    cfg = tmp_path / "short.yaml"
    cfg.write_text(yaml.safe_dump({**SMALL, "time_limit_s": 20.0, "vehicles": 4, "sight_pairs": "opposite"}))
    out = tmp_path / "out"
    assert run(["--scenarios", "1", "--seed", "3", "--variants", "dwa", "--workers", "1", "--no-certificate",
                "--out", str(out), "--scenario-config", str(cfg), "--quiet"]) == 0
    mission = load_mission(out / "failures" / failure_dir_name("dwa", 3, 0) / "scenario.yaml")
    assert mission.assigned_pairs == (("a", "c"), ("b", "d"))


@pytest.mark.parametrize("argv, message", [
    (["--sight-pairs", "diagonal", "--vehicles", "4"], "sight_pairs: use opposite (got 'diagonal')"),
    (["--sight-pairs", "opposite", "--vehicles", "5"], "needs an even number of vehicles (got 5)"),
])
def test_bad_sight_pairs_are_one_line_errors(capsys, tmp_path, argv, message):
    assert run(["--scenarios", "1", "--out", str(tmp_path / "o"), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("companion bench: ") and message in err, err
    assert len(err.strip().splitlines()) == 1


def test_bad_worker_counts_are_refused(capsys):
    for bad in ("0", "-3", "two"):
        with pytest.raises(SystemExit) as exc:
            run(["--executor", "dask", "--workers", bad])
        assert exc.value.code == 2
    assert "--workers" in capsys.readouterr().err


def _track(points, dt=0.5):
    xy = np.asarray(points, dtype=float)
    return Track(dt * np.arange(len(xy)), xy[:, 0], xy[:, 1])


def test_diagnose_names_the_vehicle_and_the_obstacle():
    mission = parse_mission(yaml.safe_dump({
        "area": {"x_min_m": 0, "y_min_m": 0, "x_max_m": 1000, "y_max_m": 1000},
        "stations": {"A": [0, 0], "B": [1000, 1000]},
        "obstacles": [{"id": "rock", "shape": "circle", "center": [500, 200], "radius_m": 50},
                      {"id": "truck", "shape": "circle", "center": [200, 500], "radius_m": 40,
                       "motion": {"type": "shuttle", "to": [600, 500], "speed_m_s": 4}}],
        "vehicles": [{"name": "a", "start": "A", "goal": "B"}, {"name": "b", "start": "B", "goal": "A"}]}))
    # a flies east along y = 500 at 5 m/s, slower than nothing: the truck (4 m/s, behind it) is
    # at x = 210 at t = 2.5 s while a sits at x = 212.5 - inside the truck's footprint.
    a = _track([(200 + 2.5 * k, 500) for k in range(6)])
    b = _track([(900, 900 - 5 * k) for k in range(6)])
    summary = {"reason": "collision", "vehicles": {"a": {"arrived": False}, "b": {"arrived": False}}}
    facts = diagnose(mission, {"a": a, "b": b}, summary)
    assert facts == {"failed_vehicles": "a", "hit_obstacle": "truck", "hit_moving": True, "hit_from_behind": True}
    out = _track([(1000, 1000), (1100, 1000), (1250, 1000)])
    facts = diagnose(mission, {"a": a, "b": out}, {**summary, "reason": "geofence"})
    assert facts["failed_vehicles"] == "b" and facts["hit_obstacle"] is None
    facts = diagnose(mission, {"a": a, "b": b},
                     {"reason": "timeout", "vehicles": {"a": {"arrived": True}, "b": {"arrived": False}}})
    assert facts["failed_vehicles"] == "b"
    assert diagnose(mission, {"a": a, "b": b}, {"reason": None})["failed_vehicles"] is None


def _sweep_row(index, weights, success=True, a=500.0, b=600.0, reason=None):
    return {**_row(index, "astar-bdwa", success, reason, a, b), **weights.columns()}


def test_sweep_summary_pairs_each_uav_with_the_paper_weights_on_the_same_scenario():
    paper, slow = Weights.default(), Weights(0.74, 0.6, 0.8)
    rows = [_sweep_row(0, paper, a=500.0, b=600.0), _sweep_row(1, paper, a=400.0, b=400.0),
            _sweep_row(2, paper, False, reason="timeout"),
            _sweep_row(0, slow, a=550.0, b=600.0), _sweep_row(1, slow, False, reason="timeout"),
            _sweep_row(2, slow, a=900.0, b=900.0)]
    ref, other = sweep.summarise(rows, paper)
    assert ref["reference"] and ref["paired_ratio"]["median"] == 1.0 and ref["little_effect"]
    # Only scenario 0 was completed by both: a 550 / 500, b 600 / 600; scenario 2 is not paired.
    assert other["paired_ratio"]["n"] == 2
    assert other["paired_ratio"]["median"] == pytest.approx(1.05)
    assert other["paired_changed_over_little"] == 0.5
    assert other["flight_time_s"]["a"]["median"] == 725.0  # 550 and 900, over its own successes
    assert other["median_vs_reference"]["a"] == pytest.approx(725.0 / 450.0 - 1.0, abs=1e-4)
    assert (other["successes"], other["reasons"]) == (2, {"timeout": 1})
    assert other["little_effect"] is False
    v = sweep.verdict([ref, other])
    assert v["sets_breaking_little_effect"] == ["0.74/0.6/0.8"] and v["claim_holds"] is False
    assert "does not hold for 1 of 1 weight sets" in sweep.verdict_text(v)


def test_sweep_weights_end_to_end_with_a_replayable_gallery(tmp_path):
    # A 20 s limit makes every run a timeout: each lands in the gallery with its weights set.
    cfg = tmp_path / "short.yaml"
    cfg.write_text(yaml.safe_dump({**SMALL, "time_limit_s": 20.0}))
    out = tmp_path / "out"
    assert cli_main(["sweep", "weights", "--scenarios", "1", "--seed", "3", "--heading", "0.1", "--distance", "0.6",
                     "--sightline", "0.8,3", "--workers", "1", "--out", str(out), "--scenario-config", str(cfg),
                     "--quiet"]) == 0
    rows = read_runs_csv(out / "runs.csv")
    # The paper's weights are not in this grid: they are flown first, as the reference.
    assert [Weights.from_row(r) for r in rows] == [Weights.default(), Weights(0.1, 0.6, 0.8), Weights(0.1, 0.6, 3.0)]
    saved = json.loads((out / "sweep.json").read_text())
    assert saved["summary"] == json.loads(json.dumps(sweep.summarise(rows, Weights.default())))
    for name in ("table.md", "meta.json", "weight_sweep.png", "failures/index.md"):
        assert (out / name).stat().st_size > 0, name
    for r in rows:
        weights = Weights.from_row(r)
        entry = out / "failures" / failure_dir_name(r["variant"], 3, 0, weights)
        mission = load_mission(entry / "scenario.yaml")
        assert (mission.planner.weight_heading, mission.planner.weight_distance,
                mission.planner.weight_sightline) == (weights.heading, weights.distance, weights.sightline)
        replay = simulate(mission).summary.summary_dict()
        assert replay["vehicles"]["b"]["path_length_m"] == pytest.approx(r["b_path_length_m"])


def test_sweep_weights_refuses_bad_grids(capsys):
    for bad in ("-1", "0.3,0.3", "x", "101"):
        with pytest.raises(SystemExit) as exc:
            cli_main(["sweep", "weights", "--heading", bad])
        assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "listed twice" in err and "[0, 100]" in err


def test_orca_without_its_extra_is_refused_before_anything_flies(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrvo", None)  # as when the orca extra is not installed
    out = tmp_path / "bench"
    code = cli_main(["bench", "--variants", "astar-bdwa,orca", "--scenarios", "2", "--workers", "1",
                     "--quiet", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "pip install -e '.[orca]'" in err
    assert not (out / "runs.csv").exists()
