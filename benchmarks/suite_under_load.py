"""The load acceptance: the test suite, N times in a row, while busy loops hog the cores.

Starts ``--loops`` busy Python loops (default 2: one per core of the 2-core CI machine), runs
``python -m pytest -n 2`` (the README's command) ``--runs`` times, and prints each run's result
and the tests that failed in it. The busy loops are stopped when it ends, however it ends (each
is also started under ``timeout``, so none can outlive ``--max-minutes``). Exit 0 only when
every run passed.

    python benchmarks/suite_under_load.py [--runs 5] [--loops 2] [-- PYTEST ARGS]

Extra arguments after ``--`` replace the default pytest arguments (``-n 2``), e.g. one file:
``python benchmarks/suite_under_load.py --runs 3 -- -n 1 tests/top/test_companion_safety.py``.
On a machine shared with others, run it in a network namespace of its own so that its ports
cannot collide: ``unshare -n sh -c 'ip link set lo up; python benchmarks/suite_under_load.py'``.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUSY = "while True: pass"
SUMMARY = re.compile(r"^=*\s*(\d+ (?:passed|failed|error).*?) in [\d.]+s")
FAILED = re.compile(r"^(FAILED|ERROR) (\S+)")


def start_loops(n: int, max_minutes: float) -> list[subprocess.Popen]:
    return [subprocess.Popen(["timeout", str(int(max_minutes * 60)), sys.executable, "-c", BUSY])
            for _ in range(n)]


def stop_loops(loops: list[subprocess.Popen]) -> None:
    for p in loops:
        p.terminate()  # timeout passes the TERM on to its loop
    for p in loops:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


def _stop_group(proc: subprocess.Popen) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
            proc.wait(10)
            return
        except ProcessLookupError:
            return
        except subprocess.TimeoutExpired:
            continue


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def one_run(pytest_args: list[str], log: Path) -> tuple[int, str, list[str]]:
    """Run pytest once; (exit code, its summary line, the failed test ids)."""
    with open(log, "w") as out:
        # A session of its own, so that an interrupted run takes its xdist workers and the
        # stubs and companions they started down with it instead of orphaning them.
        proc = subprocess.Popen([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *pytest_args],
                                cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            code = proc.wait()
        except BaseException:
            _stop_group(proc)
            raise
    summary, failed = "", []
    for line in log.read_text(errors="replace").splitlines():
        if (m := SUMMARY.match(line)) is not None:
            summary = m.group(1)
        if (m := FAILED.match(line)) is not None:
            failed.append(m.group(2))
    return code, summary, failed


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    own, pytest_args = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, ["-n", "2"])
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5, help="runs in a row (default 5)")
    p.add_argument("--loops", type=int, default=2, help="busy loops (default 2)")
    p.add_argument("--logs", type=Path, default=Path("out/suite_under_load"), help="one pytest log per run here")
    p.add_argument("--max-minutes", type=float, default=120.0, help="the busy loops end by themselves after this")
    args = p.parse_args(own)
    if args.runs < 1 or args.loops < 0:
        p.error("--runs must be >= 1 and --loops >= 0")
    args.logs.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _interrupted)  # a kill ends it as Ctrl-C does: loops and pytest stopped
    loops = start_loops(args.loops, args.max_minutes)
    passed = 0
    try:
        print(f"{args.loops} busy loop(s); pytest {' '.join(pytest_args)}; logs in {args.logs}", flush=True)
        for i in range(1, args.runs + 1):
            started = time.monotonic()
            code, summary, failed = one_run(pytest_args, args.logs / f"run{i}.log")
            passed += code == 0
            verdict = "PASS" if code == 0 else f"FAIL (exit {code})"
            print(f"run {i}/{args.runs}: {verdict} in {time.monotonic() - started:.0f} s: {summary}", flush=True)
            for test in failed:
                print(f"    {test}", flush=True)
    except KeyboardInterrupt as exc:
        print(f"interrupted ({exc or 'Ctrl-C'}): {passed} run(s) had passed; pytest and the busy loops stopped")
        return 130
    finally:
        stop_loops(loops)
    print(f"{passed}/{args.runs} runs passed under {args.loops} busy loop(s)")
    return 0 if passed == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
