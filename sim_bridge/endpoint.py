"""One UDP socket of the stub: a pymavlink parser per peer, and where its datagrams go."""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Hashable

from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.faults import LinkFaults

if TYPE_CHECKING:
    from sim_bridge.bridge import SimBridge

MAX_PEERS_PER_SOCKET = 8  # learned peers (and parsers) kept per socket; the oldest is dropped


@dataclass
class Link:
    """One (vehicle, link) pair: encoder, fault models, where its datagrams go."""

    name: str
    encoder: Any
    faults_out: LinkFaults | None
    faults_in: LinkFaults | None


class Endpoint(asyncio.DatagramProtocol):
    def __init__(self, bridge: "SimBridge", socket_name: str, vehicle_index: int | None):
        self.bridge = bridge
        self.socket_name = socket_name
        self.vehicle_index = vehicle_index
        self.transport: asyncio.DatagramTransport | None = None
        self.default_remote: tuple[str, int] | None = None
        self.peers: OrderedDict[Hashable, Any] = OrderedDict()  # peer address -> parser

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.bridge._on_datagram(self, data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable while nobody listens yet: normal before the companion starts.
        self.bridge.stats["socket_errors"] += 1

    def parser_for(self, addr: Hashable) -> Any:
        parser = self.peers.get(addr)
        if parser is None:
            parser = mavlink.MAVLink(None, 0, 0)
            parser.robust_parsing = True
            self.bridge.admission.check_signatures(parser)
            self.peers[addr] = parser
            while len(self.peers) > MAX_PEERS_PER_SOCKET:
                self.peers.popitem(last=False)
        else:
            self.peers.move_to_end(addr)
        return parser

    def destinations(self) -> list[Hashable]:
        out: list[Hashable] = [] if self.default_remote is None else [self.default_remote]
        out += [p for p in self.peers if p != self.default_remote]
        return out
