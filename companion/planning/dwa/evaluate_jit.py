"""The compiled twins (numba) of :mod:`.evaluate`: the choice (the turn-around preference, the
weighted sum and the best rollout in one pass) and the fused pick (the heading critic toward
one target, the choice and the chosen rollout's command in one call). The same numbers bit for
bit (see :mod:`.jit`): numpy's pairwise summation is done as numpy does it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.heading_jit import _heading_toward, heading_goals_rows
from companion.planning.dwa.jit import inline, jit
from companion.planning.dwa.types import Command, LocalGoals, make_command

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.evaluate import Critics


def choose(config: DwaConfig, critics: Critics, heading: np.ndarray) -> tuple[int, float, int]:
    """:func:`.evaluate.choose`, compiled."""
    return _choose(_critic_rows(config, critics), heading, config.choice_consts)


def pick(config: DwaConfig, critics: Critics, ex: np.ndarray, ey: np.ndarray, heading_rad: float,
         target_xy: tuple[float, float]) -> Command:
    """:func:`.evaluate.pick`, compiled: one call."""
    return make_command(*_pick(one_layout(ex), one_layout(ey), float(heading_rad),
                            (float(target_xy[0]), float(target_xy[1])), _critic_rows(config, critics),
                            config.choice_consts))


def pick_goals(config: DwaConfig, critics: Critics, ex: np.ndarray, ey: np.ndarray, heading_rad: float,
               gx: np.ndarray, gy: np.ndarray, goals: LocalGoals, soonest_deg: float) -> Command:
    """:func:`.evaluate.pick_goals`, compiled: one call."""
    window = (one_layout(goals.nodes_xy), one_layout(goals.prev_nodes_xy), one_layout(goals.radius2_m2),
              bool(goals.ends_at_station), float(soonest_deg))
    return make_command(*_pick_goals(one_layout(ex), one_layout(ey), float(heading_rad), one_layout(gx), one_layout(gy),
                                  config.distinct_row, window, _critic_rows(config, critics), config.choice_consts))


_NONE = np.zeros(0)  # a critic that is off


def _critic_rows(config: DwaConfig, c: Critics) -> tuple:
    """The critics as the compiled choice reads them: one signature per kernel (each new one
    compiles or loads in flight; see app/warmup.py), so the read-only all-legal mask and
    saturated distances go as the config's writable copies (:attr:`.DwaConfig.choice_rows`,
    which the compiled code never writes)."""
    legal = c.legal if c.legal.flags.writeable else config.choice_rows[0] if c.legal is config.all_legal \
        else c.legal.copy()
    distance = c.distance if c.distance.flags.writeable else config.choice_rows[1] \
        if c.distance is config.saturated_m else c.distance.copy()
    return (legal, float(c.turn_error), distance, c.distance is config.saturated_m,
            _NONE if c.sightline is None else c.sightline, c.sightline is not None,
            _NONE if c.speed is None else c.speed, c.speed is not None)


@inline
def _block_sum(a, lo, n):
    """numpy's sum of a[lo:lo + n] for n <= 128: 8 accumulators, then the rest in order."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo:lo + 8].copy()
    i = 8
    while i < n - (n % 8):
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@jit
def _pairwise_sum(a, lo, n):
    """numpy's pairwise summation of a[lo:lo + n]: blocks of <= 128, halves (the first a
    multiple of 8) added pairwise. numpy recurses; here explicit stacks do (a recursive version
    segfaulted in a process that loaded it from numba's cache)."""
    if n <= 128:
        return _block_sum(a, lo, n)
    seg_lo, seg_n = np.empty(64, np.int64), np.empty(64, np.int64)
    phase, left = np.zeros(64, np.int64), np.empty(64)
    depth, ret = 0, 0.0
    seg_lo[0], seg_n[0] = lo, n
    while True:
        m = seg_n[depth]
        half = m // 2 - (m // 2) % 8
        if phase[depth] == 0 and m <= 128:  # a leaf: its sum goes to the parent
            ret = _block_sum(a, seg_lo[depth], m)
            depth -= 1
        elif phase[depth] == 0:  # descend into the first half
            phase[depth] = 1
            depth += 1
            seg_lo[depth], seg_n[depth], phase[depth] = seg_lo[depth - 1], half, 0
            continue
        elif phase[depth] == 1:  # the first half is summed: descend into the second
            left[depth] = ret
            phase[depth] = 2
            depth += 1
            seg_lo[depth], seg_n[depth], phase[depth] = seg_lo[depth - 1] + half, m - half, 0
            continue
        else:  # both halves summed
            ret = left[depth] + ret
            depth -= 1
        if depth < 0:
            return ret


@jit
def _legal_sum(critic, legal, everyone, buf):
    """critic.sum() when everyone is legal, else critic[legal].sum(), as numpy sums them."""
    if everyone:
        return 0.0 + _pairwise_sum(critic, 0, len(critic))
    n = 0
    for i in range(len(critic)):
        if legal[i]:
            buf[n] = critic[i]
            n += 1
    return 0.0 + _pairwise_sum(buf, 0, n)


@jit
def _add_term(total, started, critic, scale, saturated, sat_value):
    """total (+)= critic * scale (a saturated critic is the constant sat_value * scale)."""
    for i in range(len(total)):
        term = sat_value * scale if saturated else critic[i] * scale
        total[i] = total[i] + term if started else term


@jit
def _choose(critics, heading, window):
    """The turn-around preference, the weighted sum and the best rollout in one pass:
    evaluate.choose (commit_turn, evaluate, argmax). ``w``: (w_h, w_d, w_s, w_v);
    ``turn_error``: the goal's bearing off the nose when the preference applies, else NaN.
    Returns (best, its total, how many are legal)."""
    legal, turn_error, distance, saturated, sightline, has_s, speed, has_v = critics
    yaw_rates, speeds, final_dheading, w, sat_value, sat_sums, slope, fixed, cap_m = window
    n_s = len(legal)
    ok = legal.copy()
    if not np.isnan(turn_error):
        any_toward = False
        for i in range(n_s):
            if legal[i] and yaw_rates[i] * turn_error >= 0.0:
                any_toward = True
        if any_toward:
            for i in range(n_s):
                ok[i] = legal[i] and yaw_rates[i] * turn_error >= 0.0
    n_legal = 0
    for i in range(n_s):
        n_legal += ok[i]
    everyone = n_legal == n_s
    total = np.zeros(n_s)
    if fixed:
        _add_term(total, False, heading, w[0] / 180.0, False, 0.0)
        if w[1] != 0.0 and sat_value > 0.0:
            _add_term(total, True, distance, w[1] / sat_value, False, 0.0)
        if has_s and w[2] != 0.0:
            _add_term(total, True, sightline, w[2] / cap_m, False, 0.0)
        if has_v and w[3] != 0.0:
            _add_term(total, True, speed, w[3], False, 0.0)
    else:
        buf = np.empty(n_s)
        started = False
        for k in range(4):
            if w[k] == 0.0 or (k == 2 and not has_s) or (k == 3 and not has_v):
                continue
            critic = heading if k == 0 else distance if k == 1 else sightline if k == 2 else speed
            if k == 2 and slope:  # sums need non-negative terms
                critic = critic + cap_m
            if k == 1 and saturated:
                norm = sat_sums[n_s if everyone else n_legal]
            else:
                norm = _legal_sum(critic, ok, everyone, buf)
            if norm > 0.0:
                _add_term(total, started, critic, w[k] / norm, k == 1 and saturated, sat_value)
                started = True
    best = -1
    for i in range(n_s):
        if not everyone and not ok[i]:
            total[i] = -np.inf
        v = total[i]
        if best < 0 or np.isnan(v) and not np.isnan(total[best]) or v > total[best]:
            best = i
    return best, total[best], n_legal


@jit
def _pick(ex, ey, heading_rad, target, critics, window):
    """The heading critic toward (tx, ty) at the prediction points (ex, ey) with headings
    heading_rad + final_dheading, then the choice; returns the chosen rollout's (yaw rate,
    speed, heading, distance and sightline scores, total, legal count): a Command's fields."""
    tx, ty = target
    _, _, distance, _, sightline, has_s, _, _ = critics
    yaw_rates, speeds, final_dheading, _, _, _, _, _, _ = window
    final = np.empty(len(ex))
    for i in range(len(ex)):
        final[i] = heading_rad + final_dheading[i]
    heading = _heading_toward(ex, ey, final, tx, ty)
    best, total, n_legal = _choose(critics, heading, window)
    s = sightline[best] if has_s else 0.0
    return yaw_rates[best], speeds[best], heading[best], distance[best], s, total, n_legal


@jit
def _pick_goals(ex, ey, heading_rad, gx, gy, rows, goals, critics, window):
    """:func:`_pick` with the heading critic over a goal window (heading_jit._heading_goals),
    rollout i's points in row rows[i] of (gx, gy)."""
    _, _, distance, _, sightline, has_s, _, _ = critics
    yaw_rates, speeds, final_dheading, _, _, _, _, _, _ = window
    final = np.empty(len(ex))
    for i in range(len(ex)):
        final[i] = heading_rad + final_dheading[i]
    heading = heading_goals_rows(ex, ey, final, gx, gy, rows, goals)
    best, total, n_legal = _choose(critics, heading, window)
    s = sightline[best] if has_s else 0.0
    return yaw_rates[best], speeds[best], heading[best], distance[best], s, total, n_legal
