"""The link guard relays on its own thread: a busy event loop delays no datagram.

Real UDP on loopback: a fake autopilot, a fake MAVSDK on the guard's private port and a second
sender. The test's coroutine blocks the event loop (a busy-wait, as a long planner step would)
while the datagrams are sent and must be received; the guard's thread alone can move them.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.errors import LinkConflict
from companion.vehicle.link_guard import LOOPBACK, guarded_port

WAIT_S = 0.5  # the least time the event loop stays blocked
ARRIVAL_S = 2.0  # bounds a datagram that must arrive (a loaded machine); a free one takes microseconds
SILENCE_S = 0.3  # how long a datagram that must not arrive is waited for


def _heartbeat(system_id: int) -> bytes:
    enc = mavlink.MAVLink(None, system_id, 1)
    msg = enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, mavlink.MAV_STATE_ACTIVE)
    return msg.pack(enc)


def _udp(port: int = 0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((LOOPBACK, port))
    sock.settimeout(ARRIVAL_S)
    return sock


def _free_port() -> int:
    with _udp() as s:
        return s.getsockname()[1]


def _received(sock: socket.socket, timeout_s: float = ARRIVAL_S) -> tuple[bytes, tuple[str, int]] | None:
    sock.settimeout(timeout_s)
    try:
        return sock.recvfrom(65535)
    except TimeoutError:
        return None


def _busy(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def _guard_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("link-guard-")]


async def _relay_while_the_loop_is_blocked() -> dict:
    port = _free_port()
    seen: dict = {}
    async with guarded_port(LOOPBACK, port, system_id=1, vehicle="a") as guard:
        with _udp() as autopilot, _udp(guard.mavsdk_port) as mavsdk, _udp() as spoofer:
            started = time.monotonic()
            # Everything below runs without one turn of the event loop.
            autopilot.sendto(_heartbeat(1), (LOOPBACK, port))
            seen["to_mavsdk"] = _received(mavsdk)
            relay = seen["to_mavsdk"][1] if seen["to_mavsdk"] else None
            if relay is not None:
                mavsdk.sendto(b"setpoint", relay)
            seen["to_autopilot"] = _received(autopilot)
            spoofer.sendto(_heartbeat(1), (LOOPBACK, port))
            spoofer.sendto(_heartbeat(7), (LOOPBACK, port))  # another system id: relayed as before
            seen["from_spoofer"] = _received(mavsdk)
            seen["after_spoof"] = _received(mavsdk, SILENCE_S)
            seen["conflict"] = guard.conflict
            seen["event_during_block"] = guard.conflicted.is_set()
            _busy(max(0.0, WAIT_S - (time.monotonic() - started)))
            seen["blocked_s"] = time.monotonic() - started
            await asyncio.wait_for(guard.conflicted.wait(), 2.0)
            seen["autopilot"], seen["spoofer"] = autopilot.getsockname(), spoofer.getsockname()
            seen["dropped"] = guard.dropped
        seen["threads_in_flight"] = len(_guard_threads())
    seen["threads_after"] = len(_guard_threads())
    with _udp(port):  # the port is free again
        pass
    return seen


def test_datagrams_pass_while_the_event_loop_is_blocked_and_a_second_source_is_a_conflict():
    seen = asyncio.run(_relay_while_the_loop_is_blocked())
    assert seen["blocked_s"] >= WAIT_S
    assert seen["to_mavsdk"] is not None and seen["to_mavsdk"][0] == _heartbeat(1)
    assert seen["to_autopilot"] is not None and seen["to_autopilot"][0] == b"setpoint"
    # The spoofed system 1 never reached MAVSDK; its system 7 frame did, and nothing else.
    assert seen["from_spoofer"] is not None and seen["from_spoofer"][0] == _heartbeat(7)
    assert seen["after_spoof"] is None
    a, s = seen["autopilot"], seen["spoofer"]
    assert seen["conflict"] == f"link conflict: system id 1 from two sources {a[0]}:{a[1]} and {s[0]}:{s[1]}"
    assert not seen["event_during_block"]  # set on the loop, once it runs again
    assert seen["dropped"] == 1
    assert seen["threads_in_flight"] == 1 and seen["threads_after"] == 0


def test_mavsdk_replies_go_to_the_autopilot_only_and_strangers_on_the_private_port_are_ignored():
    async def main():
        port = _free_port()
        async with guarded_port(LOOPBACK, port, system_id=1) as guard:
            with _udp() as autopilot, _udp(guard.mavsdk_port) as mavsdk, _udp() as stranger:
                autopilot.sendto(_heartbeat(1), (LOOPBACK, port))
                relay = _received(mavsdk)[1]
                stranger.sendto(b"from a stranger", relay)
                mavsdk.sendto(b"reply", relay)
                return _received(autopilot), _received(autopilot, SILENCE_S)

    first, second = asyncio.run(main())
    assert first is not None and first[0] == b"reply"
    assert second is None


def test_a_taken_port_is_a_link_conflict_and_leaves_no_thread():
    async def main():
        with _udp() as taken:
            async with guarded_port(LOOPBACK, taken.getsockname()[1], system_id=1, vehicle="a"):
                pass

    with pytest.raises(LinkConflict, match="cannot listen on udp 127.0.0.1:"):
        asyncio.run(main())
    assert not _guard_threads()


RELAY_CHILD = """
import asyncio, sys
from companion.vehicle.link_guard import LOOPBACK, guarded_port

async def main():
    async with guarded_port(LOOPBACK, int(sys.argv[1]), system_id=1) as guard:
        print(guard.mavsdk_port, flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
        print(guard.stale_setpoints, flush=True)

asyncio.run(main())
"""


def _setpoint(x: float, target: int = 1) -> bytes:
    enc = mavlink.MAVLink(None, 245, 190)
    return enc.set_position_target_local_ned_encode(0, target, 1, mavlink.MAV_FRAME_BODY_NED, 0xDC7, x, 0, 0,
                                                    1.0, 0, 0, 0, 0, 0, 0, 0.1).pack(enc)


def _command(n: int) -> bytes:
    enc = mavlink.MAVLink(None, 245, 190)
    return enc.command_long_encode(1, 1, mavlink.MAV_CMD_DO_SET_MODE, n, 1, 0, 0, 0, 0, 0, 0).pack(enc)


def _wait_stopped(pid: int, timeout_s: float = 10.0) -> None:
    """Until every thread of ``pid`` is stopped (state T in /proc): on a loaded machine a thread
    running on another core relays a while after SIGSTOP is sent."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        states = []
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(FileNotFoundError):  # a thread that just ended
                states.append((task / "stat").read_text().rpartition(")")[2].split()[0])
        if states and all(state in "tT" for state in states):
            return
        time.sleep(0.001)
    raise AssertionError(f"process {pid} not stopped after {timeout_s} s")


def test_a_stalled_relay_forwards_only_the_newest_queued_setpoint_per_target_and_the_rest_in_order():
    """The relay's process is stopped (SIGSTOP: as a machine under load would) while MAVSDK queues
    setpoints and commands; once it runs again, the autopilot gets every command in order and,
    per target, only the newest setpoint, in its place."""
    port = _free_port()
    child = subprocess.Popen([sys.executable, "-c", RELAY_CHILD, str(port)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        mavsdk_port = int(child.stdout.readline())
        with _udp() as autopilot, _udp(mavsdk_port) as mavsdk:
            autopilot.sendto(_heartbeat(1), (LOOPBACK, port))
            relay = _received(mavsdk)[1]
            os.kill(child.pid, signal.SIGSTOP)
            try:
                _wait_stopped(child.pid)  # the signal lands when the kernel next runs each thread
                queued = ([_command(1)] + [_setpoint(float(i)) for i in range(20)] + [_command(2)]
                          + [_setpoint(100.0 + i, target=2) for i in range(5)] + [_setpoint(20.0), _command(3)])
                for data in queued:
                    mavsdk.sendto(data, relay)
            finally:
                os.kill(child.pid, signal.SIGCONT)
            got = []
            while (item := _received(autopilot, SILENCE_S if got else ARRIVAL_S)) is not None:
                got.append(item[0])
        out, _ = child.communicate("", timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert got == [_command(1), _command(2), _setpoint(104.0, target=2), _setpoint(20.0), _command(3)]
    assert int(out.split()[-1]) == len(queued) - len(got)
