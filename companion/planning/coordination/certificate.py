"""The occlusion certificate: can the sight line of a pair (higher, lower in priority) be kept
blocked, for the whole flight and at closest approach, and if not, after what departure hold of
the higher vehicle? One per scored pair (``Mission.sight_pairs``: the assigned pairs, or the two
vehicles first in priority), each judged alone: the pair's two vehicles, nobody else.

Both questions are decided exactly on the space-time graph of :mod:`spacetime` (the mission
grid, the lower vehicle's step, waits allowed for it), against the higher vehicle after a hold at
its station, forecast as the coordinated plan forecasts the first vehicle (the caller's forecast,
from :func:`companion.planning.flight.forecast.vehicle_forecast`: by default flown alone headless
with the variant that flies, ``coordination.forecast: route`` its A* route at cruise), so that
for the first vehicle the certificate and the plan judge the same flight. A longer hold never
hurts: the lower vehicle can spend it waiting where it is (its start is as blocked as at time 0),
so the least hold is found by bisection over multiples of the step, up to the longest hold that
still lets the higher vehicle arrive within the time limit. Only the first vehicle in priority
may hold under the mission's rule (``coordination.hold_s_max``); for any other higher vehicle the
least hold says what a hold would achieve, and the rule allows none.

Given a ``budget`` (:mod:`budget`), a question the search could not settle before it ran out is
*undecided within budget*, said as such; within the budget the answers are the same as without.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from companion.planning.budget import Budget, BudgetSpent
from companion.planning.coordination.search import Blocking, feasible, problem_for
from companion.planning.grid import OccupancyGrid, rasterise
from companion.planning.metrics import pair_name
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.timed import held
from companion.planning.timed_route import TimedRoute

if TYPE_CHECKING:
    from collections.abc import Sequence

    from uav_model.mission import Mission


@dataclass(frozen=True)
class OcclusionCertificate:
    """Whether the line ``higher``-``lower`` can be kept blocked, under the mission's rule (the
    higher vehicle may hold up to ``hold_s_max``: 0 unless it is the first in priority,
    ``higher_holds``) and with the least hold that allows it."""

    higher: str
    lower: str
    hold_s_max: float
    step_s: float
    resolution_m: float
    whole_flight: bool
    closest_approach: bool
    whole_flight_min_hold_s: float | None    # None: no hold up to ``searched_hold_s`` suffices
    closest_approach_min_hold_s: float | None
    searched_hold_s: float
    whole_flight_decided: bool = True  # False: the budget ran out first (whole_flight is then False)
    closest_approach_decided: bool = True
    higher_holds: bool = True  # the higher vehicle is the first in priority: the rule may let it hold

    @property
    def pair(self) -> str:
        """The pair's key, as the metrics name it (``<higher>-<lower>``)."""
        return pair_name(self.higher, self.lower)

    @property
    def verdict(self) -> str:
        """One word for tables: feasible / needs-hold / infeasible / undecided (closest approach)."""
        if not self.closest_approach_decided:
            return "undecided"
        if self.closest_approach_min_hold_s is None:
            return "infeasible"
        return "feasible" if self.closest_approach_min_hold_s == 0 else "needs-hold"

    def summary_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["verdict"] = self.verdict
        return out

    def describe(self) -> str:
        """Two lines for ``companion plan`` / ``validate``."""
        def part(ok: bool, hold: float | None, decided: bool = True) -> str:
            if not decided:
                return "undecided within budget"
            if ok and not hold:
                return "feasible"
            if ok:
                return f"feasible with a {hold:.0f} s hold"
            if hold is None:
                return f"infeasible (no hold up to {self.searched_hold_s:.0f} s helps)"
            return f"infeasible under the rule; needs a {hold:.0f} s hold"
        rule = ("never waits" if self.higher_holds else "is not held") if self.hold_s_max == 0 \
            else f"may hold up to {self.hold_s_max:g} s"
        return (f"occlusion certificate ({self.higher} {rule}; {self.resolution_m:g} m cells, "
                f"{self.step_s:.2f} s steps): sight line {self.higher}-{self.lower} blocked\n"
                f"  whole flight: {part(self.whole_flight, self.whole_flight_min_hold_s, self.whole_flight_decided)}\n"
                f"  at closest approach: "
                f"{part(self.closest_approach, self.closest_approach_min_hold_s, self.closest_approach_decided)}")

    def advice(self, variant: str, timed_variants: tuple[str, ...]) -> str | None:
        """What keeps the sight line blocked when ``variant`` will not: a timed variant (which
        plans it) and the departure hold it needs. None when nothing would, or nothing needs to change."""
        hold = self.closest_approach_min_hold_s if self.closest_approach_decided else None
        if hold is None or not timed_variants or (hold > 0 and not self.higher_holds):
            return None
        question = "the whole flight" if self.whole_flight_min_hold_s == hold else "at closest approach"
        setting = "" if hold <= self.hold_s_max + 1e-9 else f" and coordination.hold_s_max: {math.ceil(hold)}"
        if variant in timed_variants:
            return None if not setting else (
                f"the sight line {self.higher}-{self.lower} can be kept blocked {question} with a "
                f"{hold:.0f} s departure hold of {self.higher}: set{setting[4:]}")
        how = f"with a {hold:.0f} s departure hold of {self.higher}" if hold else "without a hold"
        return (f"variant {variant} does not plan the sight line; {timed_variants[0]} keeps "
                f"{self.higher}-{self.lower} blocked {question} {how}: --variant {timed_variants[0]}{setting}")


def certificates_doc(certificates: "Sequence[OcclusionCertificate]") -> dict[str, dict[str, Any]] | None:
    """Every pair's certificate as summary.json has it, by pair (None: no certificate)."""
    return {c.pair: c.summary_dict() for c in certificates} or None


def hold_partner(mission: "Mission") -> str | None:
    """The vehicle whose sight line the first vehicle's departure hold is for: the lower vehicle of
    the first scored pair (``Mission.sight_pairs``) whose higher vehicle is the first in priority;
    None when no pair has it (nobody hides from the first vehicle: it never holds)."""
    first = mission.by_priority[0].name
    return next((low for high, low in mission.sight_pairs if high == first), None)


def least_hold(mission: "Mission", top: TimedRoute, blocking: Blocking, max_hold_s: float,
               grid: OccupancyGrid, shadows: SightShadows, memo: dict | None = None,
               margin_m: float = 0.0, known_at_max: bool = False, budget: Budget | None = None, *,
               lower: str | None = None) -> float | None:
    """The least hold (a multiple of the lower vehicle's step, <= ``max_hold_s``) of the higher
    vehicle that makes ``blocking`` feasible for ``lower`` (default: the second in priority), or
    None. ``margin_m``: see :func:`search.solve`; ``known_at_max``: the caller knows
    ``max_hold_s`` suffices. ``top``: the higher vehicle's forecast without a hold,
    held back by each hold tried (:func:`timed.held`). ``budget``: charged by every search;
    raises :class:`budget.BudgetSpent` when it runs out."""
    higher = mission.vehicle(top.vehicle)
    hider = lower or mission.by_priority[1].name
    memo = {} if memo is None else memo

    def ok(i: int) -> bool:
        others = (held(top, i * step),)
        problem = problem_for(mission, grid, shadows, hider, others, higher.speed_m_s, memo, budget=budget,
                              pair_alone=True)
        return feasible(problem, blocking, margin_m)

    step = problem_for(mission, grid, shadows, hider, (), higher.speed_m_s).model.step_s
    hi = math.floor(max_hold_s / step + 1e-9)
    if ok(0):
        return 0.0
    if hi <= 0 or not (known_at_max or ok(hi)):
        return None
    lo = 0  # ok(lo) is False, ok(hi) is True
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return hi * step


def certify(mission: "Mission", top: TimedRoute | None, *, pair: tuple[str, str] | None = None,
            grid: OccupancyGrid | None = None, shadows: SightShadows | None = None,
            max_hold_s: float | None = None, budget: Budget | None = None) -> OcclusionCertificate | None:
    """The certificate of ``pair`` (higher, lower in priority; default: the two vehicles first
    in priority; None with a single vehicle), the higher flying ``top``: its forecast without a
    hold (for the first vehicle, as the coordinated plan of the variant that flies forecasts
    it); None when the forecast itself ran out of budget (both questions are then undecided).
    Holds are searched up to ``max_hold_s`` (default: the longest that lets the higher vehicle
    still arrive within the time limit). ``budget``: the work allowed (:mod:`budget`); what is
    not settled within it is undecided."""
    if len(mission.vehicles) < 2:
        return None
    grid = grid or rasterise(mission.world, mission.planner.grid_resolution_m)
    shadows = shadows or SightShadows(mission.world, grid)
    order = mission.by_priority
    higher, lower = (mission.vehicle(n) for n in (pair or (order[0].name, order[1].name)))
    step = problem_for(mission, grid, shadows, lower.name, (), higher.speed_m_s).model.step_s
    holds = higher.name == order[0].name
    limit = mission.coordination.hold_s_max if holds else 0.0
    whole = near = None
    searched = float("nan")
    decided = 0  # questions settled: 0, 1 (whole flight) or 2
    try:
        if top is not None:  # None: the forecast ran out of budget, nothing is decided
            flight_s = float(top.t_s[-1] - top.t_s[0])
            searched = max(0.0, mission.safety.time_limit_s - flight_s) if max_hold_s is None else max_hold_s
            memo: dict = {}
            whole = least_hold(mission, top, Blocking.WHOLE_FLIGHT, searched, grid, shadows, memo, budget=budget,
                               lower=lower.name)
            decided = 1
            near = whole if whole == 0.0 else least_hold(  # whole-flight blocking is blocked at closest approach
                mission, top, Blocking.CLOSEST_APPROACH, searched if whole is None else whole, grid, shadows, memo,
                known_at_max=whole is not None, budget=budget, lower=lower.name)
            decided = 2
    except BudgetSpent:
        pass
    return OcclusionCertificate(
        higher=higher.name, lower=lower.name, hold_s_max=limit, step_s=step,
        resolution_m=grid.resolution_m,
        whole_flight=whole is not None and whole <= limit + 1e-9,
        closest_approach=near is not None and near <= limit + 1e-9,
        whole_flight_min_hold_s=whole, closest_approach_min_hold_s=near, searched_hold_s=searched,
        whole_flight_decided=decided >= 1, closest_approach_decided=decided >= 2, higher_holds=holds)
