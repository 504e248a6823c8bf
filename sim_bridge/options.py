"""The stub's options (what ``sim-bridge``'s flags set) and its start-up error."""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass, field
from pathlib import Path

from sim_bridge.energy import EnergyModel
from sim_bridge.faults import FaultConfig
from sim_bridge.streams import API_PROFILE, GCS_PROFILE, StreamProfile


class SimBridgeError(RuntimeError):
    """The stub cannot start (e.g. a socket cannot be bound)."""


@dataclass(frozen=True)
class SimOptions:
    speedup: float = 1.0
    host: str = "127.0.0.1"  # where the companion and the GCS listen
    bind_host: str | None = None  # the stub's own address; None: loopback if host is loopback, else 0.0.0.0
    api_port_base: int = 14540
    api_ports: tuple[int, ...] | None = None  # explicit port per vehicle (tests: free ports); overrides the base
    gcs_port: int | None = 14550  # None: no GCS link
    physics_dt_s: float = 0.02
    seed: int = 0
    faults: FaultConfig = field(default_factory=FaultConfig)  # applied to the API links
    faults_on_gcs: bool = False
    tlog_dir: Path | None = None
    tlog_per_vehicle: bool = False  # also one .tlog per vehicle beside the combined one
    speed_headroom: float = 1.0  # vehicle speed limit = mission speed * headroom
    energy: EnergyModel = field(default_factory=EnergyModel)
    api_profile: StreamProfile = API_PROFILE
    gcs_profile: StreamProfile = GCS_PROFILE
    min_tick_wall_s: float = 0.004  # the loop wakes at most this often and runs the steps due
    # Behind by more than this (the process was not scheduled), sim time slips instead of
    # jumping: a jump would run the offboard-loss clock over setpoints still queued in the socket.
    max_catchup_sim_s: float = 0.4
    params: tuple[tuple[str, float], ...] = ()  # parameter values at boot (NAME, VALUE), as a SITL startup script
    allow_sysids: frozenset[int] | None = None  # obey only these sender system ids (None: anyone, as PX4)
    signing_key: bytes | None = field(default=None, repr=False)  # MAVLink 2 signing: sign out, refuse unsigned in

    def api_port(self, index: int) -> int:
        """The port vehicle ``index`` sends its API link to."""
        if self.api_ports is not None:
            return self.api_ports[index]
        return self.api_port_base + index

    @property
    def resolved_bind_host(self) -> str:
        if self.bind_host is not None:
            return self.bind_host
        try:
            return "127.0.0.1" if ipaddress.ip_address(self.host).is_loopback else "0.0.0.0"
        except ValueError:  # a host name
            return "127.0.0.1" if self.host == "localhost" else "0.0.0.0"
