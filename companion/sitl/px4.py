"""Real PX4 SITL (SIH physics) for ``companion run --sim px4`` and the ``px4`` test tier.

One PX4 instance per mission vehicle: instance i is vehicle i, answers as system i + 1, sends its
offboard-API link to UDP 127.0.0.1:14540 + i and its GCS link to 14550 (PX4 SITL's fixed ports),
and starts at its vehicle's station (the mission's origin and station, through uav_model.frames).

PX4 is found through ``--px4-dir``, else ``PX4_SITL_DIR``: a PX4 SITL build directory holding
``bin/px4`` and ``etc/`` (``PX4-Autopilot/build/px4_sitl_default``, or a prebuilt copy). PX4's
startup script runs its modules through ``bin/px4-<module>`` aliases, which a build makes as
symlinks to ``px4``; a copy that flattened them into small text files (a shared, read-only copy
may have) cannot run them. So every launch runs PX4 from a private bin directory of symlinks in
its work directory: each alias and ``px4`` itself point at the real ``bin/px4``. Nothing of PX4 is
copied or changed.

Each instance runs in its own session with a private work directory (parameters, dataman, ULog)
and its console output in ``px4-<vehicle>.log``. It is stopped with SIGTERM, then SIGKILL after a
bound, whatever happens to the flight, and it gets SIGTERM from the kernel if the process that
started it dies (PR_SET_PDEATHSIG), so a crashed companion leaves no PX4 behind.
"""

from __future__ import annotations

import asyncio
import ctypes
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from companion.cli.errors import BadInput
from companion.errors import LinkConflict, LinkError
from companion.sitl.embedded import port_busy
from uav_model.frames import local_to_geodetic
from uav_model.mission import Mission

PX4_DIR_ENV = "PX4_SITL_DIR"
API_PORT_BASE = 14540  # PX4 SITL: instance i's offboard-API link sends to 14540 + i
GCS_PORT = 14550  # and its GCS link to 14550
SIH_QUADX = {"PX4_SYS_AUTOSTART": "10040", "PX4_SIM_MODEL": "sihsim_quadx", "PX4_SIMULATOR": "sihsim"}
READY_MARK = b"Startup script returned successfully"
HOW_TO_SET = f"give --px4-dir DIR or set {PX4_DIR_ENV}=DIR (a PX4 SITL build: bin/px4 and etc/)"
_PR_SET_PDEATHSIG = 1


def find_px4(given: str | os.PathLike | None = None, env: Mapping[str, str] = os.environ) -> Path:
    """The PX4 SITL directory from ``--px4-dir`` (``given``), else ``PX4_SITL_DIR``; BadInput
    naming what is missing and how to set it."""
    raw, source = (given, "--px4-dir") if given is not None else (env.get(PX4_DIR_ENV), PX4_DIR_ENV)
    if not raw:
        raise BadInput(f"--sim px4: no PX4 given: {HOW_TO_SET}")
    root = Path(raw).expanduser()
    if not root.is_dir():
        raise BadInput(f"{source} {root}: no such directory; {HOW_TO_SET}")
    missing = [p for p in ("bin/px4", "etc") if not (root / p).exists()]
    if missing:
        raise BadInput(f"{source} {root}: no {' and no '.join(missing)} there; {HOW_TO_SET}")
    if not os.access(root / "bin" / "px4", os.X_OK):
        raise BadInput(f"{source} {root}: bin/px4 is not executable; {HOW_TO_SET}")
    return root


def check_system_ids(mission: Mission) -> None:
    """PX4 SITL instance i answers as system i + 1: BadInput unless every vehicle's id agrees."""
    for v in mission.vehicles:
        if v.system_id != v.index + 1:
            raise BadInput(f"{mission.source}: vehicles[{v.index}] ({v.name}): system_id {v.system_id}, but PX4 "
                           f"SITL instance {v.index} answers as system {v.index + 1}: set it to {v.index + 1} "
                           "or leave it out")


def homes(mission: Mission) -> dict[str, tuple[float, float, float]]:
    """Each vehicle's PX4 home (lat_deg, lon_deg, alt_amsl_m): its start station."""
    return {v.name: local_to_geodetic(mission.origin, *v.start_enu_m) for v in mission.vehicles}


def private_bin(px4_dir: Path, dest: Path) -> Path:
    """``dest`` filled with symlinks: ``px4`` and every ``px4-<module>`` alias to the real
    ``bin/px4``, anything else (``px4-alias.sh``) to itself. Works whether the aliases are
    symlinks (a build tree) or flattened into files (a copy)."""
    dest.mkdir(parents=True, exist_ok=True)
    exe = (px4_dir / "bin" / "px4").resolve()
    for entry in sorted((px4_dir / "bin").iterdir()):
        is_alias = entry.name == "px4" or (entry.name.startswith("px4-") and not entry.name.endswith(".sh"))
        (dest / entry.name).symlink_to(exe if is_alias else entry.resolve())
    return dest


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the parent dies (Linux; elsewhere a no-op)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass


@dataclass(frozen=True)
class Px4Options:
    px4_dir: Path
    speedup: float = 1.0  # PX4_SIM_SPEED_FACTOR; PX4 scales its loss timeouts with it
    log_dir: Path | None = None  # px4-<vehicle>.log here (None: in the work directory)
    params: Mapping[str, str] = field(default_factory=dict)  # PX4 parameters at boot (PX4_PARAM_<NAME>)
    ready_timeout_s: float = 90.0  # wall: boot to the end of PX4's startup script (1-7 s idle, 30+ s at load 25)
    stop_grace_s: float = 5.0  # wall: SIGTERM to SIGKILL


class Px4Fleet:
    """PX4 SIH instances for a mission's vehicles (blocking calls; :func:`px4_sitl` is the asyncio
    context, :func:`px4_fleet` the blocking one). ``start`` returns at once, ``wait_ready``
    blocks until every startup script has run, ``stop`` always reaps every instance."""

    def __init__(self, mission: Mission, options: Px4Options, work_dir: Path):
        check_system_ids(mission)
        self.mission = mission
        self.options = options
        self.work_dir = work_dir
        self.processes: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, IO[bytes]] = {}

    def log_path(self, name: str) -> Path:
        return (self.options.log_dir or self.work_dir) / f"px4-{name}.log"

    def log_text(self, name: str) -> str:
        return self.log_path(name).read_text(errors="replace")

    def connections(self) -> dict[str, str]:
        """The MAVSDK URL of each vehicle: where its PX4 instance sends the offboard-API link."""
        return {v.name: f"udpin://127.0.0.1:{API_PORT_BASE + v.index}" for v in self.mission.vehicles}

    def start(self) -> None:
        """Start one PX4 per vehicle (in the calling thread: the death signal follows it)."""
        exe = private_bin(self.options.px4_dir, self.work_dir / "bin") / "px4"
        etc = (self.options.px4_dir / "etc").resolve()
        for v, (lat, lon, alt) in zip(self.mission.vehicles, homes(self.mission).values()):
            work = self.work_dir / f"px4-{v.name}"
            work.mkdir(parents=True, exist_ok=True)
            env = {**os.environ, **SIH_QUADX, "PX4_HOME_LAT": f"{lat:.9f}", "PX4_HOME_LON": f"{lon:.9f}",
                   "PX4_HOME_ALT": f"{alt:.3f}", "PX4_SIM_SPEED_FACTOR": f"{self.options.speedup:g}",
                   **{f"PX4_PARAM_{k}": str(val) for k, val in self.options.params.items()}}
            self.log_path(v.name).parent.mkdir(parents=True, exist_ok=True)
            self._logs[v.name] = log = open(self.log_path(v.name), "wb")
            self.processes[v.name] = subprocess.Popen(
                [str(exe), "-d", "-i", str(v.index), str(etc), "-w", str(work)], cwd=work, env=env,
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                preexec_fn=_die_with_parent)

    def wait_ready(self) -> None:
        """Block until every instance has run its startup script; LinkError with its log's end if
        one exits or overruns ``ready_timeout_s``."""
        deadline = time.monotonic() + self.options.ready_timeout_s
        waiting = dict(self.processes)
        while waiting:
            for name, proc in list(waiting.items()):
                text = self.log_path(name).read_bytes()
                if READY_MARK in text:
                    del waiting[name]
                elif proc.poll() is not None or time.monotonic() > deadline:
                    why = (f"exited with {proc.returncode}" if proc.poll() is not None
                           else f"not ready within {self.options.ready_timeout_s:g} s")
                    raise LinkError(f"PX4 for vehicle {name!r} {why}{_hint(text)}: "
                                    f"{_tail(text)} (log: {self.log_path(name)})")
            time.sleep(0.1)

    def stop(self) -> None:
        """SIGTERM every instance's process group, SIGKILL what is left after the grace; reap all."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for proc in self.processes.values():
                try:
                    os.killpg(proc.pid, sig)
                except (ProcessLookupError, PermissionError):
                    pass
            deadline = time.monotonic() + self.options.stop_grace_s
            for proc in self.processes.values():
                try:
                    proc.wait(max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
            if all(p.returncode is not None for p in self.processes.values()):
                break
        for log in self._logs.values():
            log.close()


def _tail(text: bytes, lines: int = 4) -> str:
    return " | ".join(line.strip() for line in text.decode(errors="replace").splitlines()[-lines:])[-400:]


def _hint(text: bytes) -> str:
    if b"already running for instance" in text:
        return (" (another PX4 uses this instance number: its lock and socket are /tmp/px4_lock-N and "
                "/tmp/px4-sock-N; stop it, or run in a private /tmp)")
    return ""


async def ports_free(mission: Mission) -> None:
    """LinkConflict naming the port if PX4's API ports for the mission are taken or already in use."""
    ports = [API_PORT_BASE + v.index for v in mission.vehicles]
    for port, why in zip(ports, await asyncio.gather(*(port_busy(p) for p in ports))):
        if why is not None:
            raise LinkConflict(f"PX4 SITL: UDP port {port}: {why}; PX4's ports are fixed (14540 + instance): "
                               "stop the other autopilot or run in a private network namespace")


@contextmanager
def px4_fleet(mission: Mission, options: Px4Options, work_dir: Path | None = None) -> Iterator[Px4Fleet]:
    """PX4 for ``mission`` while the context is open, ready when it is entered (blocking)."""
    with tempfile.TemporaryDirectory(prefix="px4-sitl-", ignore_cleanup_errors=True) as tmp:
        fleet = Px4Fleet(mission, options, work_dir or Path(tmp))
        try:
            fleet.start()
            fleet.wait_ready()
            yield fleet
        finally:
            fleet.stop()


@asynccontextmanager
async def px4_sitl(mission: Mission, options: Px4Options,
                   report: Callable[[str], None] = lambda _: None) -> AsyncIterator[dict[str, str]]:
    """PX4 for ``mission`` while the context is open; yields the vehicles' MAVSDK URLs."""
    check_system_ids(mission)
    await ports_free(mission)
    report(f"starting PX4 SITL ({options.px4_dir}) at {options.speedup:g}x: vehicle i on 127.0.0.1:"
           f"{API_PORT_BASE}+i, its GCS link on {GCS_PORT}")
    with tempfile.TemporaryDirectory(prefix="px4-sitl-", ignore_cleanup_errors=True) as tmp:
        fleet = Px4Fleet(mission, options, Path(tmp))
        try:
            fleet.start()
            await asyncio.to_thread(fleet.wait_ready)
            report(f"PX4 ready: {', '.join(f'{n} (pid {p.pid})' for n, p in fleet.processes.items())}; "
                   f"logs in {fleet.log_path(mission.vehicles[0].name).parent}")
            yield fleet.connections()
        finally:
            await asyncio.to_thread(fleet.stop)
