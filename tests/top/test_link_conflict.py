"""A second UDP source for a vehicle's system id in flight, and where the companion listens.

Over real UDP against the stub (tests/data/small_swap.yaml at 20x): once vehicle a flies
OFFBOARD, a spoofer on another port sends HEARTBEATs as system 1 in HOLD and positions 5 km away
to the companion's port. The run must end as a named link conflict (not as "mode changed by
someone else"), the spoofed positions must not reach the metrics, and every vehicle holds.
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

import pytest

from tests.top.forgery import forge_as_system_1
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "tests" / "data" / "small_swap.yaml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def _udp_bound(pid: int) -> set[tuple[str, int]]:
    """The IPv4 UDP addresses process ``pid`` has bound (Linux /proc: its socket inodes in /proc/net/udp)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    out = set()
    with open("/proc/net/udp") as f:
        for line in f.readlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                ip_hex, port_hex = fields[1].split(":")
                out.add((socket.inet_ntoa(bytes.fromhex(ip_hex)[::-1]), int(port_hex, 16)))
    return out


def test_a_spoofed_second_source_in_flight_is_a_named_link_conflict(sitl, companion, tmp_path):
    stub = sitl(SMALL, speedup=20)
    run = companion.start(stub, "--no-land")
    deadline = time.monotonic() + 300.0  # bounds for a loaded machine; a free one flies in seconds
    while "OFFBOARD" not in stub.vehicle("a").modes:
        assert run.process.poll() is None and time.monotonic() < deadline, run.wait(1).tail
        time.sleep(0.1)
    time.sleep(1.0)  # well into the flight
    spoofer, _ = forge_as_system_1(stub.api_port_base, SMALL, seconds=3.0)
    result = run.wait(300)
    assert result.exit_code == 1, result.tail
    summary = result.summary
    assert summary["reason"] == "link_conflict", result.tail
    message = summary["live"]["message"]
    assert "link conflict: system id 1 from two sources 127.0.0.1:" in message, message
    assert f"and {spoofer[0]}:{spoofer[1]}" in message, message
    assert "someone else" not in result.stdout + result.stderr
    assert "FAILED (link_conflict)" in result.stdout and "why: vehicle 'a': link conflict" in result.stdout
    # The spoofer never reached MAVSDK: no 5 km jump in the flown path, and the stub saw a hold.
    speed = load_mission(SMALL).vehicle("a").speed_m_s
    a = summary["vehicles"]["a"]
    assert a["path_length_m"] <= 1.2 * speed * a["flight_time_s"] + 50.0, a
    assert stub.vehicle("a").modes[-1] != "OFFBOARD"


def test_the_embedded_stub_is_heard_on_loopback_only(companion, tmp_path):
    """Embedded mode: every UDP socket of the companion (the vehicles' ports held by the link
    guards, their relays, MAVSDK's private ports) is bound to 127.0.0.1, never 0.0.0.0."""
    run = companion.start(SMALL, "--no-land", speedup=20)
    deadline = time.monotonic() + 300.0
    bound: set[tuple[str, int]] = set()
    try:
        while time.monotonic() < deadline and run.process.poll() is None:
            bound = _udp_bound(run.pid)
            if len(bound) >= 6:  # the vehicles' ports and MAVSDK's private ones: flying
                break
            time.sleep(0.2)
    finally:
        result = run.wait(300)
    assert result.exit_code == 0, result.tail
    assert bound and all(ip == "127.0.0.1" for ip, _ in bound), bound
    assert json.loads((result.out_dir / "summary.json").read_text())["success"] is True
    stub_log = (result.out_dir / "sim_bridge.log").read_text()
    assert "sim_bridge stopped at sim t=" in stub_log and "Fatal Python error" not in stub_log  # it stopped cleanly
