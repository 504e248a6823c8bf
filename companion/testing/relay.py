"""A UDP relay between vehicles and the companion that can cut the uplink: PX4's offboard loss on
demand, without touching the downlink (as in ../shared/px4-sih/companion-runs/px4_1x_uplinkdrop).

Works in front of anything that sends first, PX4 SITL style: the stub or real PX4.
"""

from __future__ import annotations

import select
import socket
import threading
import time


class UplinkCut:
    """A UDP relay between the stub's vehicle links and the companion that can drop the uplink
    (companion -> vehicle) for a while: PX4's offboard loss without touching the downlink, as in
    companion-runs/px4_1x_uplinkdrop. Vehicle i's datagrams arrive on ``stub_port + i`` and go on
    to ``companion_port + i``; the companion's answers go back to where the vehicle sent from."""

    def __init__(self, stub_ports: list[int], companion_ports: list[int]):
        self.cut_until = 0.0
        self._stop = threading.Event()
        self._pairs = []
        for sp, cp in zip(stub_ports, companion_ports):
            down = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            down.bind(("127.0.0.1", sp))
            up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            up.bind(("127.0.0.1", 0))
            self._pairs.append((down, up, ("127.0.0.1", cp)))
        self._vehicle_addr: dict[int, tuple] = {}
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def cut(self, seconds: float) -> None:
        self.cut_until = time.monotonic() + seconds

    def _run(self) -> None:
        socks = {s: (i, kind) for i, (down, up, _) in enumerate(self._pairs)
                 for s, kind in ((down, "down"), (up, "up"))}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(socks), [], [], 0.1)
            for s in ready:
                data, addr = s.recvfrom(65535)
                i, kind = socks[s]
                down, up, companion_addr = self._pairs[i]
                if kind == "down":
                    self._vehicle_addr[i] = addr
                    up.sendto(data, companion_addr)
                elif time.monotonic() >= self.cut_until and i in self._vehicle_addr:
                    down.sendto(data, self._vehicle_addr[i])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for down, up, _ in self._pairs:
            down.close()
            up.close()
