"""Battery energy model. Pure.

The charge drains with time armed, hovering and flying: the paper's "full" and "weak" UAVs are
just different starting charges (``battery_pct`` in the mission). Voltage follows the charge
linearly between a LiPo cell's empty and full voltage; the current is what the drain implies.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class EnergyModel:
    armed_idle_pct_s: float = 0.005  # armed on the ground
    hover_pct_s: float = 0.03  # in the air, not moving
    per_speed_pct_s: float = 0.002  # extra per m/s of ground speed
    per_climb_pct_s: float = 0.01  # extra per m/s of climb
    cells: int = 4
    cell_empty_v: float = 3.5
    cell_full_v: float = 4.2
    capacity_mah: float = 5000.0

    def drain_pct_s(self, armed: bool, in_air: bool, ground_speed_m_s: float, climb_m_s: float) -> float:
        if not armed:
            return 0.0
        if not in_air:
            return self.armed_idle_pct_s
        return (self.hover_pct_s + self.per_speed_pct_s * ground_speed_m_s
                + self.per_climb_pct_s * max(0.0, climb_m_s))

    def voltage_v(self, pct: float) -> float:
        frac = min(1.0, max(0.0, pct / 100.0))
        return self.cells * (self.cell_empty_v + (self.cell_full_v - self.cell_empty_v) * frac)

    def current_a(self, drain_pct_s: float) -> float:
        # %/s of capacity -> mAh/s -> A (1 mAh/s = 3.6 A)
        return drain_pct_s / 100.0 * self.capacity_mah * 3.6

    def consumed_mah(self, start_pct: float, pct: float) -> float:
        return max(0.0, start_pct - pct) / 100.0 * self.capacity_mah


def px4_sim_battery_pct(pct: float, armed: bool, dt_s: float, drain_s: float, min_pct: float) -> float:
    """PX4 SITL's simulated battery (``battery_simulator``), used when the mission sets no charge.

    Armed, the charge falls by 100 % every SIM_BAT_DRAIN seconds, but never below
    SIM_BAT_MIN_PCT; disarmed, it is full again at once. So on PX4 a flight of a minute or more
    always reports 50 %, which is what a client sees there.
    """
    if not armed:
        return 100.0
    return max(min_pct, pct - 100.0 * dt_s / max(drain_s, 1e-3))
