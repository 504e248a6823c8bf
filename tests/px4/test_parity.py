"""Live parity: the stub against real PX4, both measured in this session by the same sequence.

:mod:`live_sequence` flies the characterisation sequence (arming at boot, auto-disarm, climb, turn,
yaw in place, over-speed, offboard loss to RTL and to Hold, OFFBOARD re-entry, landing, the mode
after landing) against one PX4 SIH instance at speed factor 4, then against the stub at the same
factor, over real UDP. Each figure of the stub must be within TOLERANCES of PX4's from the same
session (not of a table): a PX4 build that behaves differently moves the reference with it.

    PX4_SITL_DIR=../shared/px4-sih/sitl python -m pytest tests/px4/test_parity.py -p no:xdist -s
"""

from __future__ import annotations

import fcntl
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from companion.sitl.px4 import API_PORT_BASE, Px4Fleet, Px4Options
from companion.testing.px4 import LOCK_PATH, px4_dir_or_skip
from sim_bridge.testing import free_udp_port_block
from uav_model.mission import parse_mission

from live_sequence import FIGURES, LiveVehicle, SequenceError, characterise

pytestmark = [pytest.mark.px4, pytest.mark.timeout(400)]

SPEED_FACTOR = 4.0  # PX4_SIM_SPEED_FACTOR and the stub's speedup: the loss timeouts scale alike
HOME = (47.397742, 8.545594)
STARVED = 0.5  # PX4 running below this share of its speed factor (its boot, the sequence): not compared

STUB_MISSION = f"""
name: parity
origin: {{lat_deg: {HOME[0]}, lon_deg: {HOME[1]}, alt_m: 488.0}}
area: {{x_min_m: -1000, y_min_m: -1000, x_max_m: 1000, y_max_m: 1000}}
stations: {{A: [0, 0], B: [500, 500]}}
vehicles:
  - {{name: a, start: A, goal: B, cruise_alt_m: 30, spawn_heading: north}}
"""


@dataclass(frozen=True)
class Tolerance:
    same: Callable[[object, object], bool]
    stated: str
    why: str


def within(abs_tol: float, why: str) -> Tolerance:
    return Tolerance(lambda px4, stub: abs(stub - px4) <= abs_tol, f"+-{abs_tol:g}", why)


def rel(rel_tol: float, why: str) -> Tolerance:
    return Tolerance(lambda px4, stub: abs(stub - px4) <= rel_tol * abs(px4), f"+-{rel_tol:.0%}", why)


def equal(why: str) -> Tolerance:
    return Tolerance(lambda px4, stub: px4 == stub, "equal", why)


TOLERANCES: dict[str, Tolerance] = {
    "boot.arm_accepted_s": within(0.75, "PX4's boot refusal ends at 3.7-4.5 s sim between runs; tries 0.25 s apart"),
    "boot.auto_disarm_s": within(1.5, "both ends seen in the 1 Hz heartbeat, whose phase slips on a loaded stub"),
    "climb.to_19m_s": rel(0.15, "PX4's own take-off spreads 15.6-19.7 s between runs at 4x"),
    "turn.speed_m_s": rel(0.12, "the plant is fitted on PX4's 1x trace (7.84); PX4 at 4x turns at 7.2-7.7 m/s"),
    "turn.yawspeed_deg_s": rel(0.10, "ATTITUDE's body rate, noisy in PX4's tilted turn"),
    "yaw_in_place.deg_s": rel(0.10, "PX4 settles at 85-90 deg/s for 90 commanded"),
    "overspeed.speed_m_s": rel(0.06, "tilt-limited; PX4 spreads 9.6-9.95 m/s between runs"),
    "loss.mode": equal("the failsafe target is a rule (COM_OBL_RC_ACT 0 without RC: RTL)"),
    "loss.after_s": within(1.2, "COM_OF_LOSS_T x speed factor, then seen in the 1 Hz heartbeat"),
    "loss.reentry_mode": equal("PX4 re-enters OFFBOARD by itself when setpoints resume"),
    "loss_hold.mode": equal("COM_OBL_RC_ACT 5: Hold"),
    "loss_hold.after_s": within(1.2, "as loss.after_s"),
    "loss_hold.reentry_mode": equal("as loss.reentry_mode, from Hold"),
    "land.duration_s": rel(0.20, "PX4's own landing from 20 m spreads 21.5-26.6 s between runs at 4x"),
    "land.final_mode": equal("after the landing disarm PX4 returns to the mode before LAND"),
}


def arm_window_overlaps(px4: dict, stub: dict) -> bool:
    """The boot refusal ends in (last refused, accepted] on each; the two windows, widened, overlap.

    A PX4 that booted slowly is accepted at its first try: its window is then (0, accepted].
    """
    tol = 0.75
    return (px4["boot.arm_refused_until_s"] - tol < stub["boot.arm_accepted_s"]
            and stub["boot.arm_refused_until_s"] - tol < px4["boot.arm_accepted_s"])


@dataclass
class Measured:
    figures: dict
    error: str | None = None
    link_loss: float = 0.0  # the share of the vehicle's MAVLink frames the client lost
    sim_rate: float = 0.0  # sim seconds per wall second over the whole sequence


def measure(port: int, start: Callable[[], Callable[[], None]]) -> Measured:
    """The sequence on the vehicle that ``start()`` launches (sending to ``port``); ``start`` returns its stop."""
    figures: dict = {}
    with LiveVehicle(port) as v:
        stop = start()
        wall0 = time.monotonic()
        error = None
        try:
            characterise(v, figures)
        except SequenceError as e:
            error = str(e)
        finally:
            stop()
        return Measured(figures, error, v.link.loss, v.s.sim_s / max(1e-3, time.monotonic() - wall0))


def measure_stub(tmp_path: Path) -> Measured:
    mission = tmp_path / "parity.yaml"
    mission.write_text(STUB_MISSION)
    port = free_udp_port_block(1)
    log = (tmp_path / "stub.log").open("w")

    def start() -> Callable[[], None]:
        proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(mission), "--speedup", str(SPEED_FACTOR),
                                 "--no-gcs", "--api-port-base", str(port)], stdout=log, stderr=subprocess.STDOUT)

        def stop() -> None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()
        return stop
    return measure(port, start)


def measure_px4(px4_dir: Path, tmp_path: Path) -> Measured:
    mission = parse_mission(STUB_MISSION, "parity.yaml")  # PX4's home: the vehicle's start station, as the stub's
    fleet = Px4Fleet(mission, Px4Options(px4_dir, speedup=SPEED_FACTOR, log_dir=tmp_path), tmp_path / "px4-work")

    def start() -> Callable[[], None]:
        fleet.start()  # not waiting for its startup script: the sequence arms from the first heartbeat on
        return fleet.stop
    return measure(API_PORT_BASE, start)


@pytest.fixture(scope="session")
def parity(request, tmp_path_factory) -> tuple[Measured, Measured]:
    """(PX4's, the stub's) figures, each measured once per session; the table printed (``-s`` shows it)."""
    px4_dir = px4_dir_or_skip(request.config)
    with open(LOCK_PATH, "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # PX4's ports are fixed: one PX4 at a time (released on close)
        px4 = measure_px4(px4_dir, tmp_path_factory.mktemp("px4"))
    stub = measure_stub(tmp_path_factory.mktemp("stub"))
    print(f"\nsim rate: PX4 {px4.sim_rate:.2f}x, stub {stub.sim_rate:.2f}x; "
          f"frames lost: PX4 {px4.link_loss:.1%}, stub {stub.link_loss:.1%}")
    print(f"{'figure':26} {'PX4':>10} {'stub':>10}  tolerance")
    for name in FIGURES:
        a, b = px4.figures.get(name, "-"), stub.figures.get(name, "-")
        tol = TOLERANCES[name].stated if name in TOLERANCES else ""
        print(f"{name:26} {a if isinstance(a, str) else f'{a:.2f}':>10} {b if isinstance(b, str) else f'{b:.2f}':>10}  {tol}")
    return px4, stub


def test_every_figure_has_a_stated_tolerance():
    assert set(TOLERANCES) | {"boot.sim_rate", "boot.arm_refused_until_s"} == set(FIGURES)


@pytest.mark.parametrize("name", sorted(TOLERANCES))
def test_stub_figure_within_tolerance_of_px4(parity, name):
    px4, stub = parity
    if px4.sim_rate < STARVED * SPEED_FACTOR:
        pytest.skip(f"PX4 ran at {px4.sim_rate:.1f}x of sim time (asked {SPEED_FACTOR:g}x): the machine starved it, "
                    "and a starved PX4 acts on setpoints late; its figures are the machine's, not PX4's")
    for who, m in (("PX4", px4), ("stub", stub)):
        if name not in m.figures:
            pytest.fail(f"{who} gave no {name}: {m.error}")
    a, b = px4.figures[name], stub.figures[name]
    tol = TOLERANCES[name]
    if name == "boot.arm_accepted_s" and px4.figures["boot.sim_rate"] < STARVED * SPEED_FACTOR:
        pytest.skip(f"PX4 booted at {px4.figures['boot.sim_rate']:.1f}x of sim time (asked {SPEED_FACTOR:g}x): "
                    "a starved PX4's estimator settles late, its boot timing is the machine's")
    ok = arm_window_overlaps(px4.figures, stub.figures) if name == "boot.arm_accepted_s" else tol.same(a, b)
    assert ok, f"{name}: stub {b!r} vs PX4 {a!r}, tolerance {tol.stated} ({tol.why})"
