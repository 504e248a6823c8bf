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
MAX_SLIP_S = 5.0
ATTEMPTS = 3

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
  - {name: a, start: A, goal: B, cruise_alt_m: 30}  # RTL_RETURN_ALT 30 m, as PX4's RTL in that run
"""

KNOWN_DIFFERENT = {
    # PX4's LOCAL_POSITION_NED / GLOBAL_POSITION_INT altitude wanders in fast flight with a zero climb
    # command (1x: +1.8 m over this turn, 4x: -0.65 m) while its vz integrates to ~0: the estimator's,
    # not a climb, and of either sign between runs, so the plant holds its altitude (docs/sim_bridge.md).
    "offboard.turn_alt_m": "no estimator altitude drift in fast flight (PX4's is not repeatable: +1.8 m at 1x, "
                           "-0.65 m at 4x)",
}


async def run_script_against_stub(out_prefix: Path) -> tuple[str, float]:
    """The script's step log from a run against a fresh stub on a free port, and how far the stub slipped."""
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
            slipped_s = sim.slipped_s
    finally:
        if proc.returncode is None:
            proc.kill()
        await proc.wait()
    return b"".join(lines).decode(errors="replace"), slipped_s


def test_known_differences_are_all_steps():
    names = {s.name for s in STEPS}
    assert set(KNOWN_DIFFERENT) <= names
    assert len(names) == len(STEPS)


def arms_before_healthy(log_text: str) -> bool:
    """Whether the script's first arm was answered before the vehicle reported itself healthy.

    On PX4 it was (3.70 s against 4.20 s sim): the script reads 20 parameters first, which took
    0.5 s there. On a loaded machine the stub's round trips, four times compressed, can take the
    script past the 4.2 s boot settling before it arms; the stub then rightly accepts, and the run
    cannot show the boot-time refusal that the arm steps compare.
    """
    log = parse_log(log_text)
    ack = next((line.sim_s for line in log if line.text.startswith("COMMAND_ACK ARM try 1:")), None)
    healthy = next((line.sim_s for line in log if "prearm_ok=True" in line.text), None)
    return ack is not None and (healthy is None or ack < healthy)


@pytest.mark.skipif(not SCRIPT.exists(), reason=f"PX4 reference not found: {SCRIPT} (set PX4_SIH_DIR)")
@pytest.mark.timeout(360)
def test_characterise_script_on_the_stub_matches_px4_step_by_step(tmp_path):
    # Again only when the machine made the run unlike PX4's 1x one: a stalled stub slips (it does not
    # jump), so the steps, timed in sim time, survive a few seconds of it over the ~160 s run, but
    # beyond that the script outran the vehicle; and a script that arms late cannot show the refusal.
    why = ""
    for attempt in range(1, ATTEMPTS + 1):
        log_text, slipped_s = asyncio.run(run_script_against_stub(tmp_path / f"stub{attempt}"))
        (tmp_path / "stub.log").write_text(log_text)
        if slipped_s >= MAX_SLIP_S:
            why = f"the stub fell behind by {slipped_s:.1f} s"
        elif not arms_before_healthy(log_text):
            why = "the script armed only after the stub's boot settling"
        else:
            break
    else:
        pytest.fail(f"in {ATTEMPTS} runs none was like PX4's 1x run (last: {why}; the machine is too "
                    f"slow to compare step by step); last log: {tmp_path / 'stub.log'}")
    differing = compare(parse_log(PX4_LOG.read_text()), parse_log(log_text))
    unexpected = {k: v for k, v in differing.items() if k not in KNOWN_DIFFERENT}
    now_matching = sorted(set(KNOWN_DIFFERENT) - set(differing))
    assert not unexpected, f"steps that differ from PX4 (PX4, stub): {unexpected}\nlog: {tmp_path / 'stub.log'}"
    assert not now_matching, f"steps that now match PX4: take them off KNOWN_DIFFERENT: {now_matching}"


@pytest.mark.skipif(not PX4_LOG.exists(), reason=f"PX4 reference not found: {PX4_LOG} (set PX4_SIH_DIR)")
def test_a_late_first_arm_is_told_apart_from_px4s_early_one():
    assert arms_before_healthy(PX4_LOG.read_text())
    late = ("[w   4.49 s    4.16] SYS_STATUS health=0x1000002f prearm_ok=True present=0x1000002f\n"
            "[w   4.60 s    4.32] COMMAND_ACK ARM try 1: MAV_RESULT_ACCEPTED\n")
    assert not arms_before_healthy(late)
    assert not arms_before_healthy("[w   4.49 s    4.16] SYS_STATUS health=0x0 prearm_ok=False\n")
