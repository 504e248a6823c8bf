"""What a live run adds to its summary.json beyond the scored flight, as typed records.

    link = LinkRecord("in-process", speedup=20.0)      # how the vehicles were reached
    LiveSchedule.of(plan, flight)                       # the timed variant's schedule as flown

Each serialises itself (``summary_dict``) into the keys ``summary.json`` has under ``live``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from companion.app.flight_plan import FlightPlan
    from companion.app.pilot import FlightContext


@dataclass(frozen=True)
class LinkRecord:
    """How a run reached its vehicles: ``connections`` (a URL per vehicle, or ``embedded``,
    ``in-process``, ``px4``), the simulator's speed-up, and the embedded stub's link loss and
    latency (None when there is no embedded stub)."""

    connections: str | dict[str, str]
    speedup: float | None = None
    loss: float | None = None
    latency_ms: float | None = None

    def summary_dict(self) -> dict[str, Any]:
        return {"connections": self.connections, "speedup": self.speedup, "loss": self.loss,
                "latency_ms": self.latency_ms}


@dataclass(frozen=True)
class LiveSchedule:
    """The timed variant's schedule in a live run: the plan's departure hold and what each lower
    vehicle's plan keeps, how far the schedule clocks fell behind sim time, the extra hold the
    first vehicle took, and (with schedule clocks) the in-flight re-plans per vehicle."""

    departure_hold_s: float
    blocking: dict[str, str]
    worst_lag_s: float | None  # None: no schedule clocks flew
    departure_hold_extra_s: float | None  # None: no kept hold
    replans: dict[str, int] | None = None  # None: no schedule clocks flew
    replan_tries: dict[str, int] | None = None
    replan_errors: int | None = None

    @classmethod
    def of(cls, plan: FlightPlan, flight: FlightContext | None) -> LiveSchedule | None:
        """``plan``'s schedule as ``flight`` flew it (None: no flight context); None when the
        plan has no coordinated schedule."""
        co = plan.coordinated
        if co is None:
            return None
        clocks = None if flight is None else flight.clocks
        kept = None if flight is None else flight.kept_hold
        return cls(round(co.hold_s, 3), {n: b.value for n, b in co.blocking.items()},
                   None if clocks is None else round(flight.worst_lag_s, 3),
                   None if kept is None else round(kept.extra_s or 0.0, 3),
                   None if clocks is None else dict(clocks.replans),
                   None if clocks is None else dict(clocks.tries),
                   None if clocks is None else flight.replan_errors)

    def summary_dict(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"departure_hold_s": self.departure_hold_s, "blocking": dict(self.blocking),
                               "worst_lag_s": self.worst_lag_s,
                               "departure_hold_extra_s": self.departure_hold_extra_s}
        if self.replans is not None:
            doc.update(replans=dict(self.replans), replan_tries=dict(self.replan_tries or {}),
                       replan_errors=self.replan_errors)
        return doc
