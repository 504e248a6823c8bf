"""A budget of work for searches that may take long (the occlusion certificate): the core says
what it spends, the caller decides when that is enough.

The core calls ``budget.spend(units)`` at its natural steps: one unit per tick of a headless
flight, per grown reachable set and per allowed-cell mask of a space-time search, and a sight
shadow's cost per shadow mask (:mod:`shadow`: its obstacles' circles and vertices). It never reads
a clock. :class:`WorkBudget` counts those units (deterministic: the same mission stops at the same
place on every machine); a caller that bounds wall time passes its own object with the same
``spend`` (``companion validate``'s reads the clock there, and shows progress).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from companion.planning.errors import PlanningError


class BudgetSpent(PlanningError):
    """The work budget ran out before the search decided."""


class Budget(Protocol):
    def spend(self, units: int = 1) -> None:
        """Record ``units`` of work; raise :class:`BudgetSpent` when the budget is gone."""


@dataclass
class WorkBudget:
    """At most ``units`` units of work (see the module doc for what a unit is)."""

    units: int
    spent: int = 0

    def spend(self, units: int = 1) -> None:
        self.spent += units
        if self.spent > self.units:
            raise BudgetSpent(f"work budget of {self.units} units spent")


def spend(budget: Budget | None, units: int = 1) -> None:
    """``budget.spend(units)``, or nothing without a budget."""
    if budget is not None:
        budget.spend(units)
