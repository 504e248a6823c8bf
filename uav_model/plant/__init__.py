"""The plants a mission can choose, and the one step each is flown with.

- ``multicopter``: PX4's velocity controller on SIH's quadrotor (:mod:`.multicopter`), fitted to
  PX4 SITL traces; the default.
- ``unicycle``: the paper's ideal vehicle (:mod:`.unicycle`), kept so that the paper's tables
  stay reproducible.

State and command types are in :mod:`.state` (PX4's local NED frame); all are re-exported here.

The SITL stub and the headless runner both fly ``step_for(plant)``.
"""

from __future__ import annotations

from enum import Enum
from typing import Callable, Mapping

from uav_model.plant import multicopter, unicycle
from uav_model.plant.multicopter import MulticopterLimits
from uav_model.plant.state import HOVER, KinematicState, VelocityCommand, VelocityFrame
from uav_model.plant.unicycle import VehicleLimits, step

__all__ = ["HOVER", "KinematicState", "MulticopterLimits", "Plant", "PlantLimits", "Step", "VehicleLimits",
           "VelocityCommand", "VelocityFrame", "initial_state", "limits_for", "step", "step_for"]


class Plant(Enum):
    MULTICOPTER = "multicopter"
    UNICYCLE = "unicycle"


PlantLimits = VehicleLimits | MulticopterLimits
Step = Callable[[KinematicState, VelocityCommand, PlantLimits, float], KinematicState]

_STEPS: dict[Plant, Step] = {Plant.MULTICOPTER: multicopter.step, Plant.UNICYCLE: unicycle.step}


# How long the plant may trail the planner's unicycle rollouts: the multicopter's velocity lags
# its heading for ~2 s (time to 90 % in a turn: docs/sim_bridge.md, Dynamics); the unicycle is exact.
TRACKING_LAG_S = {Plant.MULTICOPTER: 2.0, Plant.UNICYCLE: 0.0}


def step_for(plant: Plant) -> Step:
    """The pure ``step(state, command, limits, dt_s)`` of ``plant``."""
    return _STEPS[plant]


def limits_for(plant: Plant, *, speed_m_s: float, max_yaw_rate_rad_s: float, max_accel_m_s2: float,
               max_climb_m_s: float = 3.0, max_alt_m: float = 500.0,
               params: Mapping[str, float] | None = None) -> PlantLimits:
    """The limits ``plant`` is flown with.

    The unicycle takes the mission's speed, turn rate and acceleration. The multicopter takes
    PX4's parameters (``params``, PX4 names; PX4 defaults for any absent) and ignores the
    mission's: PX4 does not know them.
    """
    if plant is Plant.UNICYCLE:
        return VehicleLimits(max_speed_m_s=speed_m_s, max_yaw_rate_rad_s=max_yaw_rate_rad_s,
                             max_accel_m_s2=max_accel_m_s2, max_climb_m_s=max_climb_m_s, max_alt_m=max_alt_m)
    return MulticopterLimits.from_params(params or {}, max_alt_m=max_alt_m)


def initial_state(plant: Plant, state: KinematicState, limits: PlantLimits) -> KinematicState:
    """``state`` ready to fly on ``plant``: a multicopter already cruising holds its tilt."""
    if plant is Plant.MULTICOPTER:
        assert isinstance(limits, MulticopterLimits)
        return multicopter.trimmed(state, limits)
    return state
