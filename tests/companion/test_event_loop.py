"""The companion's process ends after a failure even when a worker thread is stuck in a C call.

Each case runs in its own Python process (a stuck non-daemon thread would otherwise hold pytest),
with a timeout: a hang fails the test instead of stalling the run."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

STUCK_WORKER = textwrap.dedent("""
    import asyncio, threading
    from companion.app.event_loop import leave, run_bounded

    async def main():
        loop = asyncio.get_running_loop()
        loop.run_in_executor(None, threading.Event().wait)  # as MAVSDK's call to a silent vehicle
        await asyncio.sleep(0.05)
        raise RuntimeError("the flight failed")

    try:
        run_bounded(main())
    except RuntimeError as exc:
        print("caught:", exc, flush=True)
    raise SystemExit(leave(1, grace_s=0.3))
""")

CLEAN = textwrap.dedent("""
    import asyncio
    from companion.app.event_loop import leave, run_bounded

    async def main():
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, sum, [1, 2])
        asyncio.get_running_loop().create_task(asyncio.sleep(3600))  # a task left behind is cancelled
        return "done"

    print(run_bounded(main()), flush=True)
    raise SystemExit(leave(0, grace_s=5.0))
""")


def _run(code: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    return proc, time.monotonic() - started


def test_a_worker_thread_blocked_in_a_call_does_not_hold_the_process():
    proc, wall = _run(STUCK_WORKER)
    assert proc.returncode == 1, proc.stderr
    assert "caught: the flight failed" in proc.stdout
    assert "1 worker thread(s) still blocked after 0.3 s (companion-worker_0)" in proc.stderr
    assert wall < 30


def test_without_a_stuck_thread_the_code_is_returned_and_nothing_is_said():
    proc, _ = _run(CLEAN)
    assert (proc.returncode, proc.stdout.strip(), proc.stderr) == (0, "done", "")
