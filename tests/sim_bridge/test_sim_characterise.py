"""Step by step against real PX4: ``characterise.py`` run on the stub, its log compared with PX4's.

``../shared/px4-sih/characterise.py`` is the raw-pymavlink sequence that was run on PX4 SITL
(SIH) at 1x, giving ``characterisation/px4_sih_1x.log``. Here the same, unmodified script runs
against the stub over real UDP, time-compressed: its clock (``time.time``) runs at ``SPEEDUP``
times the wall clock and so does the stub's, so every script second is one sim second, as in a
1x run, in a quarter of the wall time. The loss timeouts stay those of a 1x run (PX4 SITL scales
them by its speed factor; a 1x run has none to scale).

Each step of :mod:`characterise_steps` must match PX4 within its tolerance, except the ones in
KNOWN_DIFFERENT, each with its reason. The test fails both ways: a listed step that now matches
(take it off the list) and an unlisted step that differs.
"""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path

import pytest

from uav_model.mission import parse_mission
from sim_bridge.bridge import SimBridge, SimOptions
from sim_bridge.testing import free_udp_ports

from characterise_steps import STEPS, compare, parse_log

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

REPO = Path(__file__).resolve().parents[2]
PX4_SIH = Path(os.environ.get("PX4_SIH_DIR", REPO.parent / "shared" / "px4-sih"))
SCRIPT = PX4_SIH / "characterise.py"
PX4_LOG = PX4_SIH / "characterisation" / "px4_sih_1x.log"
SPEEDUP = 4.0  # 160 s of the 1x script in ~40 s

# Runs the script with its clock sped up; argv: script, speedup, then the script's own arguments.
FAST_CLOCK = """
import runpy, sys, time
script, k = sys.argv[1], float(sys.argv[2])
sys.argv = [script] + sys.argv[3:]
real = time.time
t0 = real()
time.time = lambda: t0 + (real() - t0) * k
runpy.run_path(script, run_name="__main__")
"""

MISSION_YAML = """
name: characterise
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: -1000, y_min_m: -1000, x_max_m: 1000, y_max_m: 1000}
stations: {A: [0, 0], B: [500, 500]}
vehicles:
  - {name: a, start: A, goal: B}
"""

SIMCORE = "failsafes / boot / arming / landing (simcore)"
PLANT = "multicopter plant (plant)"
KNOWN_DIFFERENT = {
    # The paper's unicycle plant reads its limits from the mission; PX4's defaults come with the
    # multicopter plant.
    "param.MPC_XY_VEL_MAX": f"mission-tuned speed limit until the {PLANT}",
    "param.MPC_ACC_HOR": f"mission-tuned acceleration until the {PLANT}",
    "param.MPC_YAWRAUTO_MAX": f"mission-tuned v/r yaw-rate limit until the {PLANT}",
    "param.MPC_XY_CRUISE": f"mission-tuned cruise speed until the {PLANT}",
    "arm.first_try": f"arming is not TEMPORARILY_REJECTED during the boot yet: {SIMCORE}",
    "arm.denied_text_split_in_two": f"no 'Arming denied: Resolve system health failures first' yet: {SIMCORE}",
    "arm.accepted_at_s": f"arms before health settles (4.2 s): {SIMCORE}",
    "arm.preflight_auto_disarm_s": f"COM_DISARM_PRFLT disarms at 10.0 s, PX4 at 11.0 s: {SIMCORE}",
    "arm.preflight_disarm_text": f"'Disarmed by auto disarm: no takeoff' instead of PX4's wording: {SIMCORE}",
    "ground.offboard_no_setpoints_ack": f"DO_SET_MODE OFFBOARD without setpoints DENIED, PX4 ACCEPTED: {SIMCORE}",
    "ground.offboard_no_setpoints_mode": f"PX4 enters OFFBOARD on the ground without setpoints: {SIMCORE}",
    "ground.disarmed_stream_stop_mode": f"offboard-loss failsafe fires while disarmed; PX4's does not: {SIMCORE}",
    "takeoff.default_alt_text": f"no 'Using default takeoff altitude' text: {SIMCORE}",
    "takeoff.detected_text": f"no 'Takeoff detected' text: {SIMCORE}",
    "takeoff.climb_to_19m_s": f"no spool-up, climbs faster (12.9 s vs 19.2 s): {SIMCORE}",
    "offboard.turn_speed_m_s": f"the unicycle keeps 10 m/s in the turn, PX4 7.6: {PLANT}",
    "offboard.turn_yawspeed_rad_s": f"yaw rate as commanded, PX4 lower: {PLANT}",
    "offboard.turn_alt_m": f"no altitude drift in fast flight: {PLANT}",
    "offboard.yaw_in_place_deg_s": f"yaw rate clipped to v/r (19 deg/s), PX4 86 (MC_YAWRATE_MAX): {PLANT}",
    "loss.target_mode": f"offboard loss goes to Hold, PX4 RTL (COM_OBL_RC_ACT 0): {SIMCORE}",
    "loss.failsafe_text": f"'Offboard control lost' instead of 'Failsafe activated': {SIMCORE}",
    "loss.heartbeat_state": f"system_status ACTIVE in the failsafe, PX4 CRITICAL: {SIMCORE}",
    "loss.auto_reentry_mode": f"no automatic re-entry to OFFBOARD when setpoints resume: {SIMCORE}",
    "loss5.auto_reentry": f"no automatic re-entry to OFFBOARD from the Hold failsafe: {SIMCORE}",
    "land.text": f"no 'Landing at current position' text: {SIMCORE}",
    "land.duration_s": f"lands 20 m in 18.7 s, PX4 30.4 s: {SIMCORE}",
    "land.disarm_text": f"'Disarmed by auto disarm after landing' instead of 'Disarmed by landing': {SIMCORE}",
    "land.final_mode": f"stays in LAND after the landing disarm, PX4 goes back to the previous mode: {SIMCORE}",
}


async def run_script_against_stub(out_prefix: Path) -> str:
    """The script's step log from a run against a fresh stub on a free port."""
    (port,) = free_udp_ports(1)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", FAST_CLOCK, str(SCRIPT), str(SPEEDUP), str(port), str(out_prefix),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    lines = [await proc.stdout.readline()]  # "listening on PORT": the script is up, as when PX4 booted
    mission = parse_mission(MISSION_YAML, "characterise.yaml")
    try:
        async with SimBridge(mission, SimOptions(speedup=SPEEDUP, api_ports=(port,), gcs_port=None)) as sim:
            for v in sim.vehicles:
                v.speed_factor = 1.0  # the loss timeouts of a 1x run: this run is one, compressed
            async with asyncio.timeout(100.0):
                while line := await proc.stdout.readline():
                    lines.append(line)
            assert sim.slipped_s < 1.0, f"the stub fell behind by {sim.slipped_s:.1f} s: a step log of a slower run"
    finally:
        if proc.returncode is None:
            proc.kill()
        await proc.wait()
    return b"".join(lines).decode(errors="replace")


def test_known_differences_are_all_steps():
    names = {s.name for s in STEPS}
    assert set(KNOWN_DIFFERENT) <= names
    assert len(names) == len(STEPS)


@pytest.mark.skipif(not SCRIPT.exists(), reason=f"PX4 reference not found: {SCRIPT} (set PX4_SIH_DIR)")
def test_characterise_script_on_the_stub_matches_px4_step_by_step(tmp_path):
    log_text = asyncio.run(run_script_against_stub(tmp_path / "stub"))
    (tmp_path / "stub.log").write_text(log_text)
    differing = compare(parse_log(PX4_LOG.read_text()), parse_log(log_text))
    unexpected = {k: v for k, v in differing.items() if k not in KNOWN_DIFFERENT}
    now_matching = sorted(set(KNOWN_DIFFERENT) - set(differing))
    assert not unexpected, f"steps that differ from PX4 (PX4, stub): {unexpected}\nlog: {tmp_path / 'stub.log'}"
    assert not now_matching, f"steps that now match PX4: take them off KNOWN_DIFFERENT: {now_matching}"
