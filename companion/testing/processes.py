"""The harness's processes, started so that none outlives a test (free ports: :mod:`sim_bridge.testing`).

Every process is started in its own session with a tag in its environment, which its children
inherit. :meth:`Processes.close` stops each process group (SIGTERM, then SIGKILL) and then every
tagged process left, so no orphan (MAVSDK servers, an embedded stub) outlives a test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
import uuid
from collections.abc import Sequence
from typing import Protocol

HARNESS_ENV = "ASTAR_BDWA_HARNESS"  # tag in the environment of every process the fixtures start


class Closeable(Protocol):
    def close(self) -> None: ...


def _tagged_processes(prefix: str) -> dict[int, str]:
    """Live processes whose environment carries ``HARNESS_ENV=<prefix>...`` (pid -> command line)."""
    needle = f"\0{HARNESS_ENV}={prefix}".encode()
    found: dict[int, str] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:  # no procfs: process groups are all we can rely on
        return found
    for entry in entries:
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                env = b"\0" + f.read()
            if needle not in env:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                found[int(entry)] = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return found


def signal_group(pid: int, sig: int) -> None:
    """Send ``sig`` to process group ``pid``, if it is still there."""
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Processes:
    """The processes one fixture started; each tagged so that its descendants are found too."""

    def __init__(self) -> None:
        self._prefix = f"{uuid.uuid4().hex[:12]}-"
        self._procs: list[tuple[subprocess.Popen, str]] = []

    def spawn(self, cmd: Sequence[str], stdout, stderr) -> tuple[subprocess.Popen, str]:
        tag = f"{self._prefix}{len(self._procs)}"
        proc = subprocess.Popen(list(cmd), stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr,
                                start_new_session=True, env={**os.environ, HARNESS_ENV: tag})
        self._procs.append((proc, tag))
        return proc, tag

    @staticmethod
    def survivors(tag: str) -> dict[int, str]:
        """Processes still alive from one spawn (the process itself and all it started)."""
        return {pid: cmd for pid, cmd in _tagged_processes(tag).items()
                if _tagged_tag(pid) == tag}

    def stop(self, proc: subprocess.Popen, grace_s: float = 5.0) -> None:
        """SIGTERM the process group, SIGKILL it after ``grace_s``. Always reaps."""
        if proc.poll() is None:
            signal_group(proc.pid, signal.SIGTERM)
            try:
                proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                pass
        signal_group(proc.pid, signal.SIGKILL)  # members may outlive a leader that exited
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            pass

    def close(self, *after: Closeable) -> None:
        """Stop every process (the last started first), then close ``after`` (e.g. recorders)."""
        try:
            self._stop_all()
        finally:
            for thing in after:
                thing.close()

    def _stop_all(self) -> None:
        for proc, _ in reversed(self._procs):  # the companion before the stub it flies
            self.stop(proc)
        deadline = time.monotonic() + 5.0
        while (left := _tagged_processes(self._prefix)) and time.monotonic() < deadline:
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
            time.sleep(0.05)
        if left:
            raise RuntimeError(f"processes survived SIGKILL: {left}")


def _tagged_tag(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            for item in f.read().split(b"\0"):
                if item.startswith(f"{HARNESS_ENV}=".encode()):
                    return item.split(b"=", 1)[1].decode()
    except OSError:
        return None
    return None

