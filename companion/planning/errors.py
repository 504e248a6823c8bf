"""Typed errors of the planning core. Raised, never printed; ``str()`` is one line a user can act on.

    PlanningError                 anything the planning core refuses
     └── NoPath                   no route from start to goal (start/goal blocked or outside the
          │                       grid, goal walled in); carries ``vehicle`` and ``reason``
          └── BudgetExceeded      the search stopped early: expansion budget spent or cancelled

Catch ``NoPath`` to handle every "no route" case; catch ``BudgetExceeded`` first when a caller
wants to retry with a larger budget.
"""

from __future__ import annotations


class PlanningError(Exception):
    """Base of every error the pure planning core raises."""


class NoPath(PlanningError):
    """No route exists (or none could be found) for ``vehicle``; ``reason`` says why."""

    def __init__(self, reason: str, *, vehicle: str | None = None):
        self.reason = reason
        self.vehicle = vehicle
        super().__init__(reason)

    def __str__(self) -> str:
        who = f" for vehicle {self.vehicle!r}" if self.vehicle is not None else ""
        return f"no path{who}: {self.reason}"

    def __reduce__(self):  # keep ``vehicle`` across pickling (process pools of runs)
        return _rebuild, (type(self), self.reason, self.vehicle)

    def for_vehicle(self, vehicle: str) -> "NoPath":
        """The same error (same type) naming the vehicle it was planned for."""
        return type(self)(self.reason, vehicle=vehicle)


class BudgetExceeded(NoPath):
    """The search hit its expansion budget or was cancelled before reaching the goal."""


def _rebuild(cls: type[NoPath], reason: str, vehicle: str | None) -> NoPath:
    return cls(reason, vehicle=vehicle)
