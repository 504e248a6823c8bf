"""BDWA: one vectorised dynamic-window step with three critics (paper section IV, SPEC §1).

    plan_step(pose, goals, other, snapshot, config, separate_from=...) -> Command | NoLegalRollout

The vehicle flies at constant speed v; only the yaw rate is chosen. ``config.samples`` yaw rates
span [-v/r, v/r]; each is rolled out for the prediction time p in steps of dt. Because v and the
samples are fixed, the rollout *shapes* are fixed: they are computed once in the body frame
(cumulative yaw, cos/sin, cumulative positions) when the config is built, and each tick only
rotates and translates them (one matrix product). Nothing loops over samples or steps.

Critics (nav2 DWB style: one term per concern, each normalised over the legal candidates by its
sum as in Fox et al. 1997, then weighted):

- heading H = 180 deg - |theta_i - theta_j| at the prediction point toward the local goal
  (toward the goal the tracker would hold there: see :class:`LocalGoals`);
- distance D = the rollout's minimum clearance to the inflated obstacles (moving ones predicted
  at constant velocity), saturated at ``distance_saturation_m``;
- sightline S = min(cap, max over true obstacles crossing the UAV-UAV sight segment of
  min(extent left, extent right)), 0 when nothing crosses (BDWA only).

Legality (a rollout that fails is discarded, never scored):

- no rollout point inside an inflated obstacle (the paper's rule). A vehicle that already is
  inside an inflated zone (a moving obstacle came to it) may only fly rollouts that never get
  deeper than it is now, so the planner leads it out instead of freezing it there;
- no rollout point closer than ``min_separation_m`` to any other UAV within reach (``other``,
  or every UAV of ``separate_from``) predicted at constant velocity (same relaxation when
  already closer), all of them in one array operation. A hard rule rather than a penalty, because
  separation is a success criterion and a penalty can always be outbid by the other critics;
- no rollout point outside the geofence box (same relaxation when already outside).

When every rollout is illegal the result is :class:`NoLegalRollout`; the caller holds (a
multicopter can hover), unless the result carries an ``escape``: a rollout that stays clear
longer than hovering would, when something is coming at the vehicle.

Obstacle knowledge comes in as an :class:`ObstacleSnapshot`: what is known *now*, predicted
forward at constant velocity, identically in the headless runner and the live companion.

The package, one concern per module (nav2 DWB style):

    types       Pose, OtherUav, Command, NoLegalRollout, LocalGoals
    shapes      the body-frame rollout shapes and their placement at a pose
    config      DwaConfig (window, weights, rules; shapes precomputed once)
    snapshot    ObstacleSnapshot: obstacle arrays, merging and culling
    geometry    clearance kernels (points to inflated obstacles, points to a segment)
    heading     the heading critic H
    distance    the distance critic D
    sightline   the sightline critic S
    legality    the rules that discard rollouts, and the turn-around preference
    evaluate    normalisation and the weighted sum
    recovery    no legal rollout: spin recovery, hold, recovery on the margin, escape
    step        plan_step, wiring the above
    backend     the kernels a tick runs: numpy's, or their compiled twins (numba, the ``fast``
                extra: geometry_jit, heading_jit, sightline_jit, distance_jit, evaluate_jit),
                held by the config and chosen when it is built
"""

from companion.planning.dwa.backend import DEFAULT
from companion.planning.dwa.config import DwaConfig
from companion.planning.dwa.heading import heading_scores
from companion.planning.dwa.shapes import rollouts
from companion.planning.dwa.sightline import sightline_scores
from companion.planning.dwa.snapshot import NO_OBSTACLES, ObstacleSnapshot
from companion.planning.dwa.step import plan_step
from companion.planning.dwa.types import Command, LocalGoals, NoLegalRollout, OtherUav, Pose

inflated_clearance = DEFAULT.inflated_clearance  # the clearance a caller without a config (the flight log) reads

__all__ = ["NO_OBSTACLES", "Command", "DwaConfig", "LocalGoals", "NoLegalRollout", "ObstacleSnapshot", "OtherUav",
           "Pose", "heading_scores", "inflated_clearance", "plan_step", "rollouts", "sightline_scores"]
