"""``companion bench``: the four-variant ablation over seeded random scenarios (paper Table IV).

Registered on the main parser by :func:`add_parser`; also runs as ``python -m companion.bench``.
The options, the output directory and the flying are shared with ``companion sweep weights``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from companion.bench.executors import CONNECT_TIMEOUT_S, ExecutorKind, ExecutorSpec
from companion.bench.machine import cpu_model
from companion.bench.table import DEFAULT_VARIANTS
from companion.cli.errors import BadInput, bad_input
from uav_model.mission import VARIANTS
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
    from companion.bench.orca import BASELINES  # numpy and the planner: only when variants are chosen
    known = VARIANTS + BASELINES
    unknown = [v for v in chosen if v not in known]
    if unknown or not chosen:
        raise argparse.ArgumentTypeError(f"unknown variant(s) {', '.join(unknown) or '(none given)'}; "
                                         f"choose from {', '.join(known)}")
    if len(set(chosen)) != len(chosen):
        raise argparse.ArgumentTypeError(f"a variant is listed twice: {text}")
    return chosen


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    add_common_arguments(parser, scenarios=120, why=", as the paper's Table IV", out="bench_s<seed>_n<N>")
    parser.add_argument("--variants", type=_variant_list, default=DEFAULT_VARIANTS, metavar="V[,V...]",
                        help=f"comma-separated planner variants (default {','.join(DEFAULT_VARIANTS)}); "
                             "baseline: orca (ORCA via pyrvo, the orca extra)")
    parser.set_defaults(handler=main)
    return parser


def add_common_arguments(parser: argparse.ArgumentParser, *, scenarios: int, why: str, out: str) -> None:
    """The scenarios, the output, where the runs execute, and the progress bar (bench and sweep)."""
    parser.add_argument("--scenarios", type=positive_int, default=scenarios, metavar="N",
                        help=f"scenarios 0..N-1 of the seed (default {scenarios}{why})")
    parser.add_argument("--seed", type=int, default=2026, help="scenario seed (default 2026)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR", help=f"output directory (default {out})")
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
    parser.add_argument("--plant", choices=("multicopter", "unicycle"), default=None,
                        help="the scenarios' dynamics (default: the scenario config's, multicopter); "
                             "unicycle is the paper's ideal vehicle, for its Table IV")
    parser.add_argument("--vehicles", type=positive_int, default=None, metavar="N",
                        help="vehicles per scenario, 2 to 32 (default: the scenario config's, 2)")
    parser.add_argument("--sight-pairs", default=None, metavar="RULE",
                        help="assign sight-line pairs in every scenario (its sightline.pairs): opposite, each "
                             "vehicle with the one starting opposite it (N/2 head-on pairs, N even); "
                             "default: none assigned, the paper's pair")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--no-certificate", action="store_true",
                        help="skip each run's occlusion certificate (its cert_* columns stay empty; "
                             "it costs about as much CPU as flying the four variants)")


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
    return guarded("companion bench", _bench, args)


def guarded(prog: str, command: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """``command(args)``, with bad input and executor trouble (:class:`ExecutorError` is a
    :class:`BadInput`) as one line and exit 2."""
    try:
        return command(args)
    except BadInput as exc:
        return bad_input(exc, prog)


@dataclass(frozen=True)
class Flown:
    rows: list[dict[str, Any]]
    out: Path
    spec: ExecutorSpec
    where: str  # what ran them
    wall_s: float
    config: Any  # companion.scenarios.ScenarioConfig


def fly(args: argparse.Namespace, out: Path, variants: Sequence[str], weight_sets: Sequence[Any] = (None,)) -> Flown:
    """Scenarios 0..args.scenarios-1 of args.seed x variants x weight sets on the executor the
    options name; the failure gallery (cleared first) is written under ``out``."""
    from companion.bench import execute
    from companion.bench.executors import open_pool

    spec = executor_spec(args)
    config = scenario_config(args.scenario_config)
    if args.plant is not None:
        config = dataclasses.replace(config, plant=args.plant)
    chosen = {k: v for k, v in (("vehicles", args.vehicles), ("sight_pairs", args.sight_pairs)) if v is not None}
    if chosen:
        from companion.scenarios import ScenarioError
        try:
            config = dataclasses.replace(config, **chosen)
        except ScenarioError as exc:
            raise BadInput(str(exc)) from None
    out = make_out_dir(out)
    execute.clear_failures(out)
    with open_pool(spec) as pool:
        started = time.perf_counter()
        rows = execute.run_bench(args.seed, args.scenarios, variants, pool=pool, out_dir=out, config=config,
                                 weight_sets=weight_sets, progress=None if args.quiet else sys.stderr,
                                 certificate=not args.no_certificate)
        return Flown(rows, out, spec, pool.where, time.perf_counter() - started, config)


def finish(prog: str, flown: Flown) -> int:
    """Write the failure index; exit 1 when a run was unsafe or crashed, else 0."""
    from companion.bench.execute import write_failure_index
    from companion.planning.metrics import UNSAFE_REASONS, FailureReason
    write_failure_index(flown.rows, flown.out)
    bad = sum(1 for r in flown.rows if r["reason"] in (*UNSAFE_REASONS, FailureReason.ERROR))
    if bad:
        print(f"{prog}: {bad} run(s) unsafe or errored; see {flown.out}/failures/index.md", file=sys.stderr)
    return 1 if bad else 0


def _bench(args: argparse.Namespace) -> int:
    from companion.bench import figures
    from companion.bench.table import aggregate, format_table, markdown_table, write_runs_csv
    from companion.scenarios import config_dict

    if "orca" in args.variants:  # before anything flies, not after every other variant has
        from companion.bench.orca import pyrvo_missing
        if (why := pyrvo_missing()) is not None:
            raise BadInput(why)
    flown = fly(args, args.out or Path(f"bench_s{args.seed}_n{args.scenarios}"), args.variants)
    rows, out, spec = flown.rows, flown.out, flown.spec
    summary = aggregate(rows)
    write_runs_csv(rows, out / "runs.csv")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    (out / "table.md").write_text(markdown_table(summary) + "\n", encoding="utf-8")
    command = (f"companion bench --scenarios {args.scenarios} --seed {args.seed} "
               f"--variants {','.join(args.variants)} --plant {flown.config.plant} --vehicles {flown.config.vehicles} "
               + (f"--sight-pairs {flown.config.sight_pairs} " if flown.config.sight_pairs else "")
               + f"{spec.describe()} --out {out}")
    meta = {"command": command,
            "seed": args.seed, "scenarios": args.scenarios, "variants": list(args.variants),
            "executor": flown.where, "workers": spec.workers or (None if spec.scheduler else os.cpu_count()),
            "wall_s": round(flown.wall_s, 2), "cpu": cpu_model(), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "scenario_config": config_dict(flown.config)}
    (out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    figures.save(figures.violin_figure(rows), out / "violin.png")
    figures.save(figures.lines_figure(rows), out / "lines.png")

    print(format_table(summary))
    print(f"\n{len(rows)} runs ({args.scenarios} scenarios x {len(args.variants)} variants, seed {args.seed}) "
          f"in {flown.wall_s:.1f} s wall on {flown.where} ({cpu_model()}); results in {out}/")
    return finish("companion bench", flown)


def run(argv: list[str] | None = None) -> int:
    parser = configure(argparse.ArgumentParser(prog="companion bench", description=DESCRIPTION))
    return main(parser.parse_args(argv))
