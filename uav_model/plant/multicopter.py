"""The PX4-like multicopter plant: PX4's velocity controller flying SIH's quadrotor, as one pure step.

Fitted to PX4 SITL with SIH physics (docs/sim_bridge.md "Dynamics"). The model is PX4's own
structure with PX4's default gains, not a curve fit:

- the horizontal velocity setpoint is capped at MPC_XY_VEL_MAX; PX4's PID velocity controller
  (MPC_XY_VEL_P/I/D_ACC) asks for an acceleration, which the tilt limit MPC_TILTMAX_AIR caps at
  g tan(tilt); the integrator has PX4's tracking anti-windup (gain 2/P);
- the thrust's horizontal acceleration follows that demand through one first-order lag (the
  attitude loop, the estimator and the link lumped: the one fitted constant besides the yaw's);
- SIH's airframe has linear drag SIH_KDV / SIH_MASS (1 /s), so the tilt limit *is* the speed
  limit: 45 deg holds 9.8 m/s against drag, whatever the command above that;
- in a turn the velocity error rotates, the integrator cannot keep up, and the vehicle flies
  slower than commanded and lags its heading, as PX4 does (7.5-7.9 m/s for 10 m/s at 19 deg/s);
- the heading rate follows the yawspeed setpoint (limited by MC_YAWRATE_MAX, not by the
  mission's turn radius) through a first-order lag; ATTITUDE's yawspeed is a body rate, which
  :func:`attitude` derives from the tilt as PX4 reports it.

MPC_ACC_HOR is kept for the flight modes that use it (PX4 applies it to auto-mode trajectories,
not to offboard velocity setpoints: the traces accelerate at 5-9 m/s^2 under a 3 m/s^2 setting).
The altitude drift PX4 shows in fast flight is its estimator's, and it does not repeat between
runs (see the docs): it is not modelled. Long steps are integrated in substeps of at most
:data:`MAX_SUBSTEP_S`, so the stub (20 ms) and the headless runner (0.5 s) fly the same dynamics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Mapping

try:
    import numba
except ImportError:  # the substeps run as Python (the ``fast`` extra brings numba)
    numba = None

from uav_model.plant.state import HOVER, KinematicState, VelocityCommand, VelocityFrame

GRAVITY_M_S2 = 9.80665
MAX_SUBSTEP_S = 0.1  # the fit's metrics change by < 3 % between 5 ms and 0.1 ms substeps


@dataclass(frozen=True, slots=True)
class MulticopterLimits:
    """PX4 parameters (lower-cased PX4 names, PX4 units and defaults) and two fitted lags."""

    mpc_xy_vel_max: float = 12.0  # m/s, horizontal velocity setpoint limit
    mpc_acc_hor: float = 3.0  # m/s^2, auto-mode acceleration (not applied to offboard velocity)
    mpc_tiltmax_air: float = 45.0  # deg
    mpc_xy_vel_p_acc: float = 1.8  # 1/s
    mpc_xy_vel_i_acc: float = 0.4  # 1/s^2
    mpc_xy_vel_d_acc: float = 0.2  # dimensionless (acceleration feedback)
    mc_yawrate_max: float = 200.0  # deg/s
    mpc_z_vel_max_up: float = 3.0  # m/s
    mpc_z_vel_max_dn: float = 1.5  # m/s
    mpc_z_vel_p_acc: float = 4.0  # 1/s
    mpc_acc_up_max: float = 4.0  # m/s^2
    mpc_acc_down_max: float = 3.0  # m/s^2
    sih_kdv: float = 1.0  # N/(m/s), SIH translational drag
    sih_mass: float = 1.0  # kg
    attitude_tau_s: float = 0.3  # fitted on px4_sih_1x: thrust direction lag
    yaw_tau_s: float = 0.5  # fitted on px4_sih_1x: heading-rate lag
    max_alt_m: float = 500.0  # above home; not a PX4 parameter (the stub's ceiling)
    # (drag 1/s, tilt-limited acceleration m/s^2, yaw-rate limit rad/s): computed once, read every step
    derived: tuple[float, float, float] = field(init=False, repr=False, compare=False)
    # step length (s) -> the constants of a step of that length (see _step_constants), made at its first step
    per_step: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "derived", (
            self.sih_kdv / self.sih_mass, GRAVITY_M_S2 * math.tan(math.radians(self.mpc_tiltmax_air)),
            math.radians(self.mc_yawrate_max)))
        object.__setattr__(self, "per_step", {})

    @classmethod
    def from_params(cls, params: Mapping[str, float], **overrides: float) -> "MulticopterLimits":
        """Limits from a PX4 parameter table: each field whose PX4 name is present takes its value."""
        values = {f.name: float(params[f.name.upper()]) for f in fields(cls) if f.init and f.name.upper() in params}
        values.update(overrides)
        return cls(**values)

    # The protocol the stub's flight modes read (shared with the unicycle's VehicleLimits).
    @property
    def max_speed_m_s(self) -> float:
        return self.mpc_xy_vel_max

    @property
    def max_yaw_rate_rad_s(self) -> float:
        return math.radians(self.mc_yawrate_max)

    @property
    def max_accel_m_s2(self) -> float:
        return self.mpc_acc_hor

    @property
    def max_climb_m_s(self) -> float:
        return self.mpc_z_vel_max_up

    @property
    def yaw_p_1_s(self) -> float:
        """Yaw-angle gain that settles the lagging heading rate without overshoot (damping 0.7)."""
        return 1.0 / (2.0 * self.yaw_tau_s)

    @property
    def yaw_lag_s(self) -> float:
        """The heading rate's first-order lag: a yaw controller brakes this much early."""
        return self.yaw_tau_s

    @property
    def drag_1_s(self) -> float:
        return self.derived[0]

    @property
    def tilt_speed_m_s(self) -> float:
        """The straight-line speed the tilt limit holds against drag."""
        return self.derived[1] / self.derived[0]


def trimmed(state: KinematicState, limits: MulticopterLimits) -> KinematicState:
    """``state`` with the tilt and integrator that hold its horizontal velocity (a cruise start)."""
    k, a_max, _ = limits.derived
    an, ae = k * state.vn_m_s, k * state.ve_m_s
    a = math.hypot(an, ae)
    if a > a_max:
        an, ae = an * a_max / a, ae * a_max / a
    return KinematicState(state.north_m, state.east_m, state.down_m, state.vn_m_s, state.ve_m_s,
                          state.vd_m_s, state.yaw_rad, state.yawspeed_rad_s, an, ae, an, ae)


def attitude(state: KinematicState, accel_ne: tuple[float, float] | None = None) -> tuple[float, float, float]:
    """(roll, pitch, body yawspeed) in rad, rad, rad/s, as PX4's ATTITUDE reports them.

    The thrust leans into the horizontal acceleration it produces (the multicopter's state holds
    it; ``accel_ne`` gives it for a plant that does not, e.g. the unicycle's velocity change); the
    body z rate of a vehicle turning at heading rate psi' with that tilt is psi' cos(roll) cos(pitch).
    """
    an, ae = (state.accel_n_m_s2, state.accel_e_m_s2) if accel_ne is None else accel_ne
    c, s = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
    a_fwd = c * an + s * ae
    a_right = -s * an + c * ae
    pitch = -math.atan2(a_fwd, GRAVITY_M_S2)
    roll = math.atan2(a_right * math.cos(pitch), GRAVITY_M_S2)
    return roll, pitch, state.yawspeed_rad_s * math.cos(roll) * math.cos(pitch)


def _substeps(limits: MulticopterLimits, dt_s: float) -> tuple[int, float, float, float, float]:
    """(count, length, attitude / yaw / climb lag factors per substep) for a step of ``dt_s``."""
    n = max(1, math.ceil(dt_s / MAX_SUBSTEP_S - 1e-9))
    h = dt_s / n
    return (n, h, 1.0 - math.exp(-h / limits.attitude_tau_s), 1.0 - math.exp(-h / limits.yaw_tau_s),
            1.0 - math.exp(-h * limits.mpc_z_vel_p_acc))


def _step_constants(limits: MulticopterLimits, dt_s: float) -> tuple:
    """What :func:`step` passes the substep loop that depends on the limits and the step length
    alone, worked out at the first step of that length (a flight steps at one length)."""
    n, h, k_att, k_yaw, k_z = _substeps(limits, dt_s)
    drag, a_max, r_max = limits.derived
    p = limits.mpc_xy_vel_p_acc
    return (n, h, k_att, k_yaw, k_z, drag, a_max, p, limits.mpc_xy_vel_i_acc * h, limits.mpc_xy_vel_d_acc,
            2.0 / p,  # PX4's tracking anti-windup gain
            limits.mpc_xy_vel_max, 1.0 / (1.0 + h * drag), r_max, limits.mpc_z_vel_max_up, limits.mpc_z_vel_max_dn,
            limits.mpc_acc_up_max * h, limits.mpc_acc_down_max * h)


def step(state: KinematicState, command: VelocityCommand, limits: MulticopterLimits, dt_s: float) -> KinematicState:
    """Advance the multicopter by ``dt_s`` seconds under ``command``. Pure; non-finite commands hover."""
    isfinite = math.isfinite
    if not (isfinite(command.x_m_s) and isfinite(command.y_m_s) and isfinite(command.z_m_s)
            and isfinite(command.yawspeed_rad_s)):
        command = HOVER
    constants = limits.per_step.get(dt_s)
    if constants is None:
        constants = limits.per_step[dt_s] = _step_constants(limits, dt_s)
    n, h, k_att, k_yaw, k_z, drag, a_max, p, i_h, d, arw, v_max, inv_drag, r_max, up_max, dn_max, dvd_up, dvd_dn = \
        constants
    s = state
    (north, east, down, vn, ve, vd, yaw, r, an, ae, i_n, i_e) = _substep_loop(
        n, h, k_att, k_yaw, k_z, drag, a_max, p, i_h, d, arw, v_max, inv_drag,
        max(-r_max, min(r_max, command.yawspeed_rad_s)), max(-up_max, min(dn_max, command.z_m_s)),
        dvd_up, dvd_dn, command.frame is VelocityFrame.BODY_NED,
        command.x_m_s, command.y_m_s, s.north_m, s.east_m, s.down_m, s.vn_m_s, s.ve_m_s, s.vd_m_s, s.yaw_rad,
        s.yawspeed_rad_s, s.accel_n_m_s2, s.accel_e_m_s2, s.vel_int_n_m_s2, s.vel_int_e_m_s2)
    if down > 0.0 or down < -limits.max_alt_m:
        down = min(0.0, max(-limits.max_alt_m, down))
        vd = 0.0
    yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
    return KinematicState(north, east, down, vn, ve, vd, yaw, r, an, ae, i_n, i_e)


def _substep_loop(n, h, k_att, k_yaw, k_z, drag, a_max, p, i_h, d, arw, v_max, inv_drag, r_sp, vd_sp, dvd_up,
                  dvd_dn, body, cx, cy, north, east, down, vn, ve, vd, yaw, r, an, ae, i_n, i_e):
    """The n substeps of :func:`step` on plain numbers; compiled when numba is installed (the
    ``fast`` extra), with the same operations in the same order, so the same results."""
    cos, sin, sqrt = math.cos, math.sin, math.sqrt
    for _ in range(n):
        r += (r_sp - r) * k_yaw
        yaw += r * h
        if body:
            c, s = cos(yaw), sin(yaw)
            sp_n, sp_e = c * cx - s * cy, s * cx + c * cy
        else:
            sp_n, sp_e = cx, cy
        sp2 = sp_n * sp_n + sp_e * sp_e
        if sp2 > v_max * v_max:
            k = v_max / sqrt(sp2)
            sp_n, sp_e = sp_n * k, sp_e * k
        e_n, e_e = sp_n - vn, sp_e - ve
        # PID on the velocity error; D acts on the measured acceleration (thrust minus drag).
        dem_n = p * e_n + i_n - d * (an - drag * vn)
        dem_e = p * e_e + i_e - d * (ae - drag * ve)
        dem2 = dem_n * dem_n + dem_e * dem_e
        if dem2 > a_max * a_max:
            k = a_max / sqrt(dem2)
            lim_n, lim_e = dem_n * k, dem_e * k
        else:
            lim_n, lim_e = dem_n, dem_e
        i_n += i_h * (e_n - (dem_n - lim_n) * arw)
        i_e += i_h * (e_e - (dem_e - lim_e) * arw)
        an += (lim_n - an) * k_att
        ae += (lim_e - ae) * k_att
        vn0, ve0 = vn, ve
        vn = (vn + h * an) * inv_drag  # drag implicit: stable at any substep
        ve = (ve + h * ae) * inv_drag
        north += 0.5 * (vn0 + vn) * h
        east += 0.5 * (ve0 + ve) * h
        dvd = (vd_sp - vd) * k_z
        vd += dvd if -dvd_up <= dvd <= dvd_dn else (-dvd_up if dvd < 0.0 else dvd_dn)
        down += vd * h
    return north, east, down, vn, ve, vd, yaw, r, an, ae, i_n, i_e


substep_loop_python = _substep_loop  # the reference the compiled loop is tested against
if numba is not None:
    _substep_loop = numba.njit(cache=True, nogil=True, error_model="numpy")(_substep_loop)
