"""The harness leaves nothing behind when a scenario test fails mid-flight or times out: a user's
failing tests are run in a child pytest, then every process they started must be gone."""

from __future__ import annotations

import os
import signal
import textwrap
import uuid
from pathlib import Path

import pytest

REFERENCE = Path(__file__).resolve().parents[2] / "missions" / "paper_reference.yaml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

FAILING_TESTS = f'''
import pytest

MISSION = {str(REFERENCE)!r}


def test_fails_mid_flight(sitl, companion):
    stub = sitl(MISSION, speedup=10)
    companion.start(stub)
    stub.wait_for_mode("a", "TAKEOFF", timeout_s=60)
    assert False, "a failure while the companion flies"


@pytest.mark.timeout(6)
def test_times_out_mid_flight(companion):
    live = companion.start(MISSION, speedup=10)  # the companion's embedded stub
    live.telemetry.wait_for_clock(1e9, timeout_s=120)
'''


def _processes_with(marker: str) -> dict[int, str]:
    needle = f"\0{marker}\0".encode()
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                if needle in b"\0" + f.read() + b"\0":
                    with open(f"/proc/{entry}/cmdline", "rb") as c:
                        found[int(entry)] = c.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
    return found


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs procfs to find the processes")
def test_failed_and_timed_out_scenarios_leave_no_process_behind(tmp_path, inner_pytest):
    (tmp_path / "test_failing.py").write_text(textwrap.dedent(FAILING_TESTS))
    marker = f"HARNESS_CLEANUP_PROBE={uuid.uuid4().hex}"  # inherited by everything the child starts
    _, out = inner_pytest("test_failing.py", timeout_s=150, env=dict([marker.split("=", 1)]))
    assert "2 failed" in out, out[-3000:]
    assert "a failure while the companion flies" in out and "Timeout" in out, out[-3000:]
    left = _processes_with(marker)
    for pid in left:  # do not leak them from this test either
        os.kill(pid, signal.SIGKILL)
    assert not left, left
