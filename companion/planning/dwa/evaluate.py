"""The weighted sum of the critics, each normalised over the legal candidates (Fox et al. 1997)."""

from __future__ import annotations

import numpy as np

from companion.planning.dwa.config import DwaConfig
from companion.planning.dwa.types import Command


def evaluate(config: DwaConfig, legal: np.ndarray, heading: np.ndarray, distance: np.ndarray,
              sightline: np.ndarray | None, everyone: bool | None = None) -> np.ndarray:
    """Eval = w_h H + w_d D + w_s S, each critic normalised by its sum over the legal candidates
    (Fox et al. 1997; a critic that is zero for all of them contributes nothing); -inf where
    illegal. ``everyone``: whether every candidate is legal, if the caller knows. Term by term
    on (S,) rows: this runs every tick."""
    if everyone is None:
        everyone = bool(legal.all())
    total = None
    for weight, critic in ((config.w_h, heading), (config.w_d, distance), (config.w_s, sightline)):
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
    if total is None:
        total = np.zeros(len(heading))
    if not everyone:
        total[~legal] = -np.inf
    return total


def command_for(config: DwaConfig, i: int, heading: np.ndarray, distance: np.ndarray,
                sightline: np.ndarray | None, total: float, legal_count: int) -> Command:
    """Rollout ``i`` as the command to fly, with its raw critic values for the logs."""
    return Command(yaw_rate_rad_s=float(config.yaw_rates_rad_s[i]), speed_m_s=config.speed_m_s,
                   heading_score=float(heading[i]), distance_score=float(distance[i]),
                   sightline_score=0.0 if sightline is None else float(sightline[i]),
                   eval_score=total, legal_count=legal_count)
