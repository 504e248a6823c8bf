"""Link fault injection: packet loss, added latency and blackouts. Pure and seeded.

Each link direction owns a ``random.Random`` seeded from the run seed and the link's name, so
one link's traffic never shifts another link's loss pattern and a run with the same seed and
the same traffic drops the same packets. Blackout windows are in sim seconds.
"""

from __future__ import annotations

import random
from dataclasses import dataclass


class FaultSpecError(ValueError):
    """A fault option that cannot be used (e.g. a malformed ``--blackout``)."""


@dataclass(frozen=True, slots=True)
class Blackout:
    """Every packet of the link is lost from ``start_s`` for ``duration_s`` (sim seconds)."""

    start_s: float
    duration_s: float

    def active(self, sim_t: float) -> bool:
        return self.start_s <= sim_t < self.start_s + self.duration_s

    @classmethod
    def parse(cls, text: str) -> "Blackout":
        """``START:DURATION`` in sim seconds, e.g. ``30:5``."""
        try:
            start, duration = (float(part) for part in text.split(":"))
        except ValueError:
            raise FaultSpecError(f"blackout {text!r}: expected START:DURATION in sim seconds, e.g. 30:5") from None
        if not (start >= 0 and duration > 0):
            raise FaultSpecError(f"blackout {text!r}: START must be >= 0 and DURATION > 0")
        return cls(start, duration)


@dataclass(frozen=True, slots=True)
class FaultConfig:
    loss_p: float = 0.0  # probability that one datagram is lost
    latency_ms: float = 0.0  # added one-way delay (wall clock)
    blackouts: tuple[Blackout, ...] = ()

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss_p <= 1.0:
            raise FaultSpecError(f"loss {self.loss_p}: must be a probability in [0, 1]")
        if not 0.0 <= self.latency_ms <= 60_000.0:
            raise FaultSpecError(f"latency {self.latency_ms} ms: must be in [0, 60000]")

    @property
    def is_clean(self) -> bool:
        return self.loss_p == 0.0 and self.latency_ms == 0.0 and not self.blackouts


class LinkFaults:
    """The fault verdict for each datagram of one link direction."""

    def __init__(self, config: FaultConfig, seed: int, name: str):
        self._config = config
        self._rng = random.Random(f"{seed}/{name}")
        self._extra: list[Blackout] = []
        self.dropped = 0
        self.passed = 0

    def add_blackout(self, blackout: Blackout) -> None:
        self._extra.append(blackout)

    def blacked_out(self, sim_t: float) -> bool:
        return any(b.active(sim_t) for b in self._config.blackouts) or any(b.active(sim_t) for b in self._extra)

    def verdict(self, sim_t: float) -> float | None:
        """None: drop the datagram. Otherwise the delay in wall seconds before it goes on."""
        cfg = self._config
        # Draw for every datagram, even in a blackout, so the loss pattern after it is the same.
        lost = cfg.loss_p > 0.0 and self._rng.random() < cfg.loss_p
        if lost or self.blacked_out(sim_t):
            self.dropped += 1
            return None
        self.passed += 1
        return cfg.latency_ms / 1000.0
