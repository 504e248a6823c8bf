"""``companion bench``: the four-variant ablation over seeded random scenarios (paper Table IV).

Registered on the main parser by :func:`add_parser`; also runs as ``python -m companion.bench``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import yaml

from companion.bench.executors import CONNECT_TIMEOUT_S, ExecutorError, ExecutorKind, ExecutorSpec
from uav_model.mission import VARIANTS

DEFAULT_VARIANTS = ("astar-bdwa", "astar-bdwa-nosparse", "bdwa", "dwa")
DESCRIPTION = ("Fly seeded random scenarios (SPEC §3) with each planner variant, headless and in parallel; "
               "write runs.csv, summary.json, table.md, figures and a replayable failure gallery "
               "(paper Table IV, Fig. 11-13). Exit 1 if any run was unsafe or crashed, 2 on bad input.")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (got {value})")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds (got {text})")
    return value


def _variant_list(text: str) -> tuple[str, ...]:
    chosen = tuple(v.strip() for v in text.split(",") if v.strip())
    unknown = [v for v in chosen if v not in VARIANTS]
    if unknown or not chosen:
        raise argparse.ArgumentTypeError(f"unknown variant(s) {', '.join(unknown) or '(none given)'}; "
                                         f"choose from {', '.join(VARIANTS)}")
    if len(set(chosen)) != len(chosen):
        raise argparse.ArgumentTypeError(f"a variant is listed twice: {text}")
    return chosen


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument("--scenarios", type=positive_int, default=120, metavar="N",
                        help="scenarios 0..N-1 of the seed (default 120, as the paper's Table IV)")
    parser.add_argument("--seed", type=int, default=2026, help="scenario seed (default 2026)")
    parser.add_argument("--variants", type=_variant_list, default=DEFAULT_VARIANTS, metavar="V[,V...]",
                        help=f"comma-separated planner variants (default {','.join(DEFAULT_VARIANTS)})")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="output directory (default bench_s<seed>_n<N>)")
    add_common_arguments(parser)
    parser.set_defaults(handler=main)
    return parser


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Where the runs execute, the generator config and the progress bar (bench and sweep)."""
    parser.add_argument("--executor", choices=[k.value for k in ExecutorKind], default="local",
                        help="local: a process pool on this machine (default); dask: a Dask cluster")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="N",
                        help="local processes, or the workers of a local Dask cluster (default: os.cpu_count(); "
                             "local 1 runs in-process)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="with --executor dask: an existing scheduler, e.g. tcp://10.0.0.5:8786 "
                             "(start workers with `dask worker ADDRESS --nthreads 1`)")
    parser.add_argument("--connect-timeout", type=_positive_float, default=CONNECT_TIMEOUT_S, metavar="S",
                        help=f"with --executor dask: give up reaching the scheduler or its first worker after S "
                             f"seconds (default {CONNECT_TIMEOUT_S:g})")
    parser.add_argument("--scenario-config", type=Path, default=None, metavar="FILE",
                        help="YAML mapping overriding the generator defaults (companion.scenarios.ScenarioConfig)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def executor_spec(args: argparse.Namespace) -> ExecutorSpec:
    """The executor the options name (:class:`ExecutorError` when they contradict each other)."""
    return ExecutorSpec(ExecutorKind(args.executor), workers=args.workers, scheduler=args.scheduler,
                        connect_timeout_s=args.connect_timeout)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``bench`` to the main CLI's subparsers."""
    parser = subparsers.add_parser(
        "bench", help="four-variant ablation over seeded random scenarios (paper Table IV, Fig. 13)",
        description=DESCRIPTION)
    return configure(parser)


class BadInput(Exception):
    """Bench input that cannot be used; ``str()`` is the one line shown to the user."""


def make_out_dir(out: Path) -> Path:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"cannot create output directory {out}: {exc.strerror}") from None
    return out


def scenario_config(path: Path | None):
    from companion.scenarios import ScenarioConfig, ScenarioError
    if path is None:
        return ScenarioConfig()
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise BadInput(f"cannot read {path}: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise BadInput(f"{path}: must be a YAML mapping of ScenarioConfig fields")
    try:
        return ScenarioConfig.from_mapping(data)
    except ScenarioError as exc:
        raise BadInput(f"{path}: {exc}") from None


def main(args: argparse.Namespace) -> int:
    """Run the bench, write every artefact, print the table. Exit codes as the main CLI: 2 for
    bad input, 1 when a run was unsafe (collision, separation, geofence) or crashed, else 0
    (timeouts and holds are results, not errors)."""
    try:
        return _bench(args)
    except (BadInput, ExecutorError) as exc:
        print(f"companion bench: {exc}", file=sys.stderr)
        return 2


def _bench(args: argparse.Namespace) -> int:
    from companion.bench import execute, figures
    from companion.bench.executors import open_pool
    from companion.bench.table import aggregate, format_table, markdown_table, write_runs_csv
    from companion.scenarios import config_dict

    spec = executor_spec(args)
    config = scenario_config(args.scenario_config)
    out = make_out_dir(args.out or Path(f"bench_s{args.seed}_n{args.scenarios}"))
    execute.clear_failures(out)
    with open_pool(spec) as pool:
        started = time.perf_counter()
        rows = execute.run_bench(args.seed, args.scenarios, args.variants, pool=pool, out_dir=out,
                                 config=config, progress=None if args.quiet else sys.stderr)
        wall = time.perf_counter() - started

    summary = aggregate(rows)
    write_runs_csv(rows, out / "runs.csv")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    (out / "table.md").write_text(markdown_table(summary) + "\n", encoding="utf-8")
    command = (f"companion bench --scenarios {args.scenarios} --seed {args.seed} "
               f"--variants {','.join(args.variants)} {spec.describe()} --out {out}")
    meta = {"command": command,
            "seed": args.seed, "scenarios": args.scenarios, "variants": list(args.variants),
            "executor": pool.where, "workers": spec.workers or (None if spec.scheduler else os.cpu_count()),
            "wall_s": round(wall, 2), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "scenario_config": config_dict(config)}
    (out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    figures.save(figures.violin_figure(rows), out / "violin.png")
    figures.save(figures.lines_figure(rows), out / "lines.png")
    execute.write_failure_index(rows, out)

    print(format_table(summary))
    print(f"\n{len(rows)} runs ({args.scenarios} scenarios x {len(args.variants)} variants, seed {args.seed}) "
          f"in {wall:.1f} s wall on {pool.where}; results in {out}/")
    bad = sum(s["unsafe"] + s["reasons"].get("error", 0) for s in summary.values())
    if bad:
        print(f"companion bench: {bad} run(s) unsafe or errored; see {out}/failures/index.md", file=sys.stderr)
    return 1 if bad else 0


def run(argv: list[str] | None = None) -> int:
    parser = configure(argparse.ArgumentParser(prog="companion bench", description=DESCRIPTION))
    return main(parser.parse_args(argv))
