"""The weighted sum of the critics: the paper's sum normalisation (Fox et al. 1997) or fixed scales."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from companion.planning.dwa.heading import heading_from_ends, heading_toward
from companion.planning.dwa.legality import commit_turn
from companion.planning.dwa.types import Command, LocalGoals

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig

class Critics(NamedTuple):
    """What the choice reads besides the heading critic: which rollouts are legal (S,), the
    goal's bearing off the nose when the turn-around preference applies (NaN when it does not:
    see :func:`.legality.turn_error`), D (S,), and S and V (S,) or None when off."""

    legal: np.ndarray
    turn_error: float
    distance: np.ndarray
    sightline: np.ndarray | None
    speed: np.ndarray | None


def choose(config: DwaConfig, critics: Critics, heading: np.ndarray) -> tuple[int, float, int]:
    """The turn-around preference, the weighted sum and the best rollout: (its index, its
    total, how many rollouts are legal)."""
    legal = commit_turn(critics.legal, config, critics.turn_error)
    n_legal = int(np.count_nonzero(legal))
    total = evaluate(config, legal, heading, critics.distance, critics.sightline, n_legal == config.count,
                     critics.speed)
    best = int(total.argmax())
    return best, float(total[best]), n_legal


def pick(config: DwaConfig, critics: Critics, ex: np.ndarray, ey: np.ndarray, heading_rad: float,
         target_xy: tuple[float, float]) -> Command:
    """The command toward one target: the heading critic toward ``target_xy`` at the prediction
    points (ex, ey) of a pose heading ``heading_rad``, :func:`choose` and :func:`command_for`."""
    heading = heading_toward(ex, ey, heading_rad + config.final_dheading_rad, *target_xy)
    best, total, n_legal = choose(config, critics, heading)
    return command_for(config, best, heading, critics.distance, critics.sightline, total, n_legal)


def pick_goals(config: DwaConfig, critics: Critics, ex: np.ndarray, ey: np.ndarray, heading_rad: float,
               gx: np.ndarray, gy: np.ndarray, goals: LocalGoals, soonest_deg: float) -> Command:
    """:func:`pick` over the goal window ``goals`` (:func:`.heading.heading_from_ends`, not
    single): the rollouts are the rows of (gx, gy), spread to all by ``config.row_of`` when
    some coincide (None: they are every rollout)."""
    px, py = (gx, gy) if config.row_of is None else (gx[config.row_of], gy[config.row_of])
    heading = heading_from_ends(ex, ey, heading_rad + config.final_dheading_rad, goals, (0.0, 0.0), px, py, False,
                                soonest_deg)
    best, total, n_legal = choose(config, critics, heading)
    return command_for(config, best, heading, critics.distance, critics.sightline, total, n_legal)


def evaluate(config: DwaConfig, legal: np.ndarray, heading: np.ndarray, distance: np.ndarray,
             sightline: np.ndarray | None, everyone: bool | None = None,
             speed: np.ndarray | None = None) -> np.ndarray:
    """Eval = w_h H + w_d D + w_s S (+ w_v V), -inf where illegal. ``everyone``: whether every
    candidate is legal, if the caller knows.

    Normalisation: the paper's (Fox et al. 1997) divides each critic by its sum over the legal
    candidates, so a critic that is non-zero for one candidate only gives it its whole weight;
    ``config.fixed_scale`` divides by a fixed scale instead (see :func:`fixed_scale_total`)."""
    if everyone is None:
        everyone = bool(legal.all())
    if config.fixed_scale:
        total = fixed_scale_total(config, heading, distance, sightline, speed)
    else:
        if sightline is not None and config.sightline_slope:  # sums need non-negative terms
            sightline = sightline + config.sightline_cap_m
        total = sum_normalised_total(config, legal, everyone, heading, distance, sightline, speed)
    if not everyone:
        total[~legal] = -np.inf
    return total


def sum_normalised_total(config: DwaConfig, legal: np.ndarray, everyone: bool, heading: np.ndarray,
                         distance: np.ndarray, sightline: np.ndarray | None,
                         speed: np.ndarray | None) -> np.ndarray:
    """Each critic normalised by its sum over the legal candidates (a critic that is zero for all
    of them contributes nothing). Term by term on (S,) rows: this runs every tick."""
    total = None
    for weight, critic in ((config.w_h, heading), (config.w_d, distance), (config.w_s, sightline),
                           (config.w_v, speed)):
        if critic is None or weight == 0.0:
            continue
        if critic is config.saturated_m:  # nothing within reach: the same for every candidate
            norm = config.saturated_sums[len(critic) if everyone else int(np.count_nonzero(legal))]
            if norm > 0.0:
                term = config.distance_saturation_m * (weight / norm)
                total = np.full(len(critic), term) if total is None else total.__iadd__(term)
            continue
        norm = float(critic.sum() if everyone else critic[legal].sum())
        if norm > 0.0:
            term = critic * (weight / norm)
            if total is None:
                total = term
            else:
                total += term
    return np.zeros(len(heading)) if total is None else total


def fixed_scale_total(config: DwaConfig, heading: np.ndarray, distance: np.ndarray,
                      sightline: np.ndarray | None, speed: np.ndarray | None) -> np.ndarray:
    """Each critic on its own fixed scale: H / 180 deg, D / distance_saturation_m, S /
    sightline_cap_m, V as it is (in [0, 1]). A critic's pull is then its real spread, not its
    spread relative to the candidates' mean."""
    total = heading * (config.w_h / 180.0)
    if config.w_d and config.distance_saturation_m > 0.0:
        total = total + distance * (config.w_d / config.distance_saturation_m)
    if sightline is not None and config.w_s:
        total = total + sightline * (config.w_s / config.sightline_cap_m)
    if speed is not None and config.w_v:
        total = total + speed * config.w_v
    return total


def command_for(config: DwaConfig, i: int, heading: np.ndarray, distance: np.ndarray,
                sightline: np.ndarray | None, total: float, legal_count: int) -> Command:
    """Rollout ``i`` as the command to fly, with its raw critic values for the logs."""
    return Command(yaw_rate_rad_s=float(config.yaw_rates_rad_s[i]), speed_m_s=float(config.speeds_m_s[i]),
                   heading_score=float(heading[i]), distance_score=float(distance[i]),
                   sightline_score=0.0 if sightline is None else float(sightline[i]),
                   eval_score=total, legal_count=legal_count)
