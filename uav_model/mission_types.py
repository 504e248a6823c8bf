"""The typed mission: the frozen objects a mission file becomes (built only by :mod:`uav_model.mission`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum
from typing import Literal, get_args

from uav_model.frames import GeoOrigin
from uav_model.mission_errors import MissionError
from uav_model.mission_schema import schema_default
from uav_model.plant import Plant
from uav_model.world import World

# The paper's four (SPEC §1's ablation), then ours: the speed window, the sloped sightline critic and
# fixed-scale normalisation, tracking a timed route (docs/design.md).
Variant = Literal["astar-bdwa", "astar-bdwa-nosparse", "bdwa", "dwa", "astar-bdwa-timed"]
VARIANTS: tuple[str, ...] = get_args(Variant)


class SightlineCritic(Enum):
    PAPER = "paper"  # the depth of the obstacles crossing the sight segment, 0 when none does
    SLOPED = "sloped"  # the depth when blocked, minus the segment's clearance when open


class Normalisation(Enum):
    SUM = "sum"  # each critic over its sum on the candidates (the paper, Fox et al. 1997)
    FIXED = "fixed"  # each critic over a fixed scale


class SpawnHeading(Enum):
    """Which way a vehicle faces on the ground before it flies."""

    MISSION = "mission"  # the mission's initial_heading_deg (the paper's setting)
    NORTH = "north"  # as PX4 SITL spawns every vehicle, whatever the mission says


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    name: str
    index: int  # position in the file; sets the default system id and port
    system_id: int
    connection: str
    start: str
    goal: str
    start_enu_m: tuple[float, float]
    goal_enu_m: tuple[float, float]
    speed_m_s: float
    turn_radius_m: float
    max_accel_m_s2: float
    cruise_alt_m: float
    initial_heading_deg: float
    priority: int
    battery_pct: float | None  # None: PX4 SITL's simulated battery
    spawn_heading: SpawnHeading = SpawnHeading.MISSION

    @property
    def max_yaw_rate_rad_s(self) -> float:
        """The turn-radius limit as a yaw rate: |omega| <= v / r."""
        return self.speed_m_s / self.turn_radius_m

    @property
    def initial_heading_rad(self) -> float:
        return math.radians(self.initial_heading_deg)

    @property
    def spawn_heading_rad(self) -> float:
        """The math-angle (ENU) heading the vehicle has on the ground before take-off."""
        return self.initial_heading_rad if self.spawn_heading is SpawnHeading.MISSION else math.pi / 2


@dataclass(frozen=True, slots=True)
class PlannerSettings:
    variant: str
    grid_resolution_m: float
    yaw_rate_samples: int
    dt_s: float
    prediction_time_s: float | None
    weight_heading: float
    weight_distance: float
    weight_sightline: float
    inflation_ratio: float
    acceptance_radius_m: float
    sightline_cap_m: float
    replan_after_s: float  # 0: never re-plan (see VehiclePlanner)
    # The speed window and critics; None: the variant's choice (the paper's four: constant speed,
    # the paper's sightline critic, sum normalisation).
    speed_samples: int | None = None
    min_speed_m_s: float = float(schema_default("planner", "min_speed_m_s"))
    weight_speed: float = float(schema_default("planner", "weights", "speed"))
    sightline_critic: SightlineCritic | None = None
    normalisation: Normalisation | None = None
    # A speed window near the station for the constant-speed variants; None: the plant's choice.
    final_approach: bool | None = None

    def prediction_time_for(self, vehicle: VehicleSpec) -> float:
        """The paper's p = ceil(2*pi / ((v/r) * 2)) + 1 seconds, unless the mission fixes it."""
        if self.prediction_time_s is not None:
            return self.prediction_time_s
        return math.ceil(2.0 * math.pi / (vehicle.max_yaw_rate_rad_s * 2.0)) + 1.0


@dataclass(frozen=True, slots=True)
class SafetySettings:
    min_separation_m: float
    arrival_radius_m: float
    time_limit_s: float
    telemetry_timeout_s: float


class Forecast(Enum):
    """What the lower-priority vehicles are planned against (``coordination.forecast``)."""

    FLOWN = "flown"  # the first vehicle flown alone, headless, before departure
    ROUTE = "route"  # the first vehicle on its route at cruise speed


@dataclass(frozen=True, slots=True)
class CoordinationSettings:
    """Coordinated timing (docs/design.md): who may wait, and the space-time plan's step.
    The defaults are the schema's (``uav_model.mission_schema``)."""

    # the first vehicle in priority may hold at its station this long (paper: 0)
    hold_s_max: float = float(schema_default("coordination", "hold_s_max"))
    step_s: float = float(schema_default("coordination", "step_s"))  # nominal time step of the space-time plan
    replan: bool = bool(schema_default("coordination", "replan"))  # re-plan a lower vehicle that lags its timed plan
    forecast: Forecast = Forecast(schema_default("coordination", "forecast"))  # the first vehicle's forecast


@dataclass(frozen=True)
class Mission:
    name: str
    source: str
    description: str
    origin: GeoOrigin
    world: World
    stations: dict[str, tuple[float, float]]
    vehicles: tuple[VehicleSpec, ...]  # in file order
    planner: PlannerSettings
    safety: SafetySettings
    plant: Plant = Plant(schema_default("plant"))  # the dynamics the stub and the headless runner fly
    coordination: CoordinationSettings = CoordinationSettings()
    # ``sightline.pairs`` as the file names them, each (higher priority, lower priority); None: the
    # file names none, and the paper's pair (the first two in priority) is scored.
    assigned_pairs: tuple[tuple[str, str], ...] | None = None

    @property
    def sight_pairs(self) -> tuple[tuple[str, str], ...]:
        """The pairs whose sight line is scored, higher priority first in each: the assigned
        pairs, or the paper's pair (the two vehicles first in priority; none with one vehicle)."""
        if self.assigned_pairs is not None:
            return self.assigned_pairs
        order = self.by_priority
        return ((order[0].name, order[1].name),) if len(order) >= 2 else ()

    def hides_from(self, name: str) -> tuple[str, ...] | None:
        """The vehicles that ``name`` hides from by assignment (the other member of each assigned
        pair in which it is lower in priority), or None when the mission assigns no pairs (then
        every vehicle but the first hides from the nearest vehicle above it still flying)."""
        if self.assigned_pairs is None:
            return None
        return tuple(high for high, low in self.assigned_pairs if low == name)

    def carries_sightline(self, name: str) -> bool:
        """Whether the planner of ``name`` carries the sightline term: it hides from someone."""
        partners = self.hides_from(name)
        return self.by_priority[0].name != name if partners is None else bool(partners)

    @property
    def by_priority(self) -> tuple[VehicleSpec, ...]:
        """Vehicles in planning order: lowest priority value first, ties in file order."""
        return tuple(sorted(self.vehicles, key=lambda v: (v.priority, v.index)))

    def vehicle(self, name: str) -> VehicleSpec:
        for v in self.vehicles:
            if v.name == name:
                return v
        raise KeyError(name)

    def with_variant(self, variant: str) -> "Mission":
        """The same mission flown with another planner variant."""
        if variant not in VARIANTS:
            raise MissionError(self.source, "planner.variant", f"unknown variant {variant!r}; one of {', '.join(VARIANTS)}")
        return replace(self, planner=replace(self.planner, variant=variant))


def shared_goals(mission: Mission) -> dict[str, list[str]]:
    """Goal stations that more than one vehicle flies to, with those vehicles' names."""
    by_goal: dict[str, list[str]] = {}
    for v in mission.vehicles:
        by_goal.setdefault(v.goal, []).append(v.name)
    return {goal: names for goal, names in by_goal.items() if len(names) > 1}
