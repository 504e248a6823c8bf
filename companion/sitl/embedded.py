"""The embedded SITL stub: ``sim-bridge`` in a child process for ``companion run`` without --connect.

A child process rather than the companion's own event loop, so that the stub's physics gets the
other core and the two cannot stall each other; it is still the same MAVLink-over-UDP path an
external autopilot would use. The child runs in its own process group, which is terminated
(then killed) when the context exits, and :mod:`companion.sitl.stub_child` makes it exit by
itself if the companion dies without cleaning up.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from collections import deque
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from companion.errors import LinkConflict, LinkError
from companion.vehicle.link_probe import listen
from uav_model.mission import Mission

READY_MARK = b"running at"
TLOG_ERROR_MARK = b"tlog error:"  # sim_bridge.tlog's line when the disk refuses the recording
LOOPBACK = "127.0.0.1"  # the embedded stub's vehicles are on this host: nobody else may talk to MAVSDK
DEFAULT_PORT_BASE = 14540
PORT_PROBE_S = 0.3  # wall: an autopilot streams telemetry many times a second
PORT_BASE_STEP = 20  # the next candidate block (14540, 14560, ...), clear of PX4's GCS port 14550
PORT_BASE_TRIES = 10


@dataclass(frozen=True)
class StubOptions:
    speedup: float = 1.0
    api_port_base: int | None = None  # None: the first free block from 14540 (choose_port_base)
    gcs_port: int | None = 14550
    loss: float = 0.0
    latency_ms: float = 0.0
    seed: int = 0
    blackouts: tuple[str, ...] = ()  # START:DURATION in sim seconds, as sim-bridge --blackout takes them
    tlog_dir: Path | None = None
    log_path: Path | None = None  # the child's output; None: discarded
    params: tuple[str, ...] = ()  # autopilot parameters at boot (NAME=VALUE); none: PX4's defaults
    signing_key_file: Path | None = None  # MAVLink 2 signing: the stub signs and refuses unsigned frames

    def argv(self, mission_path: Path) -> list[str]:
        out = [sys.executable, "-m", "companion.sitl.stub_child", str(mission_path), "--speedup", f"{self.speedup:g}",
               "--api-port-base", str(self.api_port_base), "--seed", str(self.seed)]
        out += ["--no-gcs"] if self.gcs_port is None else ["--gcs-port", str(self.gcs_port)]
        if self.loss:
            out += ["--loss", f"{self.loss:g}"]
        if self.latency_ms:
            out += ["--latency-ms", f"{self.latency_ms:g}"]
        for b in self.blackouts:
            out += ["--blackout", b]
        if self.tlog_dir is not None:
            out += ["--tlog", str(self.tlog_dir)]
        for p in self.params:
            out += ["--param", p]
        if self.signing_key_file is not None:
            out += ["--signing-key", str(self.signing_key_file.absolute())]
        return out


async def port_busy(port: int) -> str | None:
    """Why the embedded stub cannot use UDP ``port`` for a vehicle link, or None if it is free
    and quiet (nobody listening on it, nobody sending to it)."""
    try:
        senders = await listen(LOOPBACK, port, PORT_PROBE_S)
    except OSError as exc:
        return f"taken by another program ({exc.strerror})"
    if senders:
        ids = ", ".join(f"system {sysid} from {h}:{p}" for sysid, addrs in sorted(senders.items()) for h, p in addrs)
        return f"another autopilot is already sending to it ({ids})"
    return None


async def choose_port_base(count: int, requested: int | None, gcs_port: int | None) -> tuple[int, str | None]:
    """The embedded stub's API port block: ``requested`` if it is free (LinkConflict naming the
    port and the --port-base fix otherwise), or the first free block from 14540. Returns the base
    and a note when it is not the default."""
    bases = [requested] if requested is not None else [
        DEFAULT_PORT_BASE + k * PORT_BASE_STEP for k in range(PORT_BASE_TRIES)]
    first_problem: str | None = None
    for base in bases:
        ports = [base + i for i in range(count)]
        if gcs_port is not None and gcs_port in ports:
            problem = f"UDP port {gcs_port} is also the GCS port"
        else:
            why = await asyncio.gather(*(port_busy(p) for p in ports))
            problem = next((f"UDP port {p}: {w}" for p, w in zip(ports, why) if w is not None), None)
        if problem is None:
            note = None if base == DEFAULT_PORT_BASE else (
                f"port {DEFAULT_PORT_BASE} busy ({first_problem}); using ports {base}+i" if requested is None else None)
            return base, note
        first_problem = first_problem or problem
        if requested is not None:
            raise LinkConflict(f"embedded stub: {problem}; pick free ports with --port-base "
                               f"(e.g. --port-base {requested + PORT_BASE_STEP})")
    raise LinkConflict(f"embedded stub: no free port block from {DEFAULT_PORT_BASE} ({first_problem}); "
                       "pick free ports with --port-base")


def connections(mission: Mission, api_port_base: int) -> dict[str, str]:
    """The MAVSDK URL of each vehicle of the embedded stub (PX4 SITL: 14540 + i), on loopback
    only (SPEC section 4): ``--connect`` is how to listen on another address."""
    return {v.name: f"udpin://{LOOPBACK}:{api_port_base + v.index}" for v in mission.vehicles}


async def _drain(stream: asyncio.StreamReader, sink: IO[bytes] | None, ready: asyncio.Event,
                 tail: deque[bytes], notices: list[str] | None) -> None:
    while line := await stream.readline():
        tail.append(line.rstrip())
        if sink is not None and not sink.closed:
            try:
                sink.write(line)
                sink.flush()
            except OSError as exc:  # a full disk: the stub keeps flying, its log ends here
                if notices is not None:
                    notices.append(f"{Path(sink.name).name} (stopped: {exc.strerror})")
                _close_quietly(sink)
        if READY_MARK in line:
            ready.set()
        if TLOG_ERROR_MARK in line and notices is not None:
            notices.append(line[line.index(TLOG_ERROR_MARK) + len(TLOG_ERROR_MARK):].decode(errors="replace").strip())


def _close_quietly(f: IO[bytes]) -> None:
    try:
        f.close()
    except OSError:
        pass


@asynccontextmanager
async def embedded_stub(mission: Mission, options: StubOptions, *, ready_timeout_s: float = 20.0,
                        notices: list[str] | None = None) -> AsyncIterator[dict[str, str]]:
    """Run the stub for ``mission`` while the context is open; yields the vehicles' URLs. The
    stub's output problems (a .tlog the disk refused, its log) are appended to ``notices``."""
    sink = open(options.log_path, "wb") if options.log_path is not None else None
    proc = await asyncio.create_subprocess_exec(
        *options.argv(Path(mission.source)), stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT, start_new_session=True)
    tail: deque[bytes] = deque(maxlen=8)
    ready = asyncio.Event()
    try:
        async with asyncio.TaskGroup() as tg:
            assert proc.stdout is not None
            drain = tg.create_task(_drain(proc.stdout, sink, ready, tail, notices), name="stub-output")
            waiter = tg.create_task(ready.wait(), name="stub-ready")
            try:
                await asyncio.wait({drain, waiter}, timeout=ready_timeout_s, return_when=asyncio.FIRST_COMPLETED)
            finally:
                waiter.cancel()
            if not ready.is_set():
                last = b" | ".join(tail).decode(errors="replace")[-400:]
                if drain.done():
                    raise LinkError(f"the embedded sim_bridge exited before it was ready: {last}")
                raise LinkError(f"the embedded sim_bridge was not ready within {ready_timeout_s:g} s: {last}")
            try:
                yield connections(mission, options.api_port_base)
            finally:
                await _terminate(proc)
    except BaseExceptionGroup as group:
        if len(group.exceptions) == 1:
            raise group.exceptions[0] from None
        raise
    finally:
        if proc.returncode is None:
            await _terminate(proc)
        if sink is not None:
            _close_quietly(sink)


async def _terminate(proc: asyncio.subprocess.Process, grace_s: float = 5.0) -> None:
    """SIGTERM the child's process group, then SIGKILL it if it does not go in time."""
    if proc.returncode is not None:
        return
    if proc.stdin is not None:
        proc.stdin.close()
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            async with asyncio.timeout(grace_s):
                await proc.wait()
            return
        except TimeoutError:
            continue
