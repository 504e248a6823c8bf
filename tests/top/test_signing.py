"""``companion run --signing-key``: MAVLink 2 signing end to end, over real UDP, real MAVSDK and the stub.

- A signed flight on the embedded stub (which gets the key too) succeeds, and frames forged
  without the key in flight (a HOLD heartbeat and positions 5 km away, as system 1 from another
  port) are dropped and counted: no mode change, no jump in the flown path.
- A stub with a key refuses an unsigned companion, a companion with another key, and an unsigned
  stub refuses nothing but is refused by a signing companion: each a one-line refusal naming
  signing, exit 2, nothing armed, within seconds.
- Bad key files exit 2 in one line before anything starts.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.testing import free_udp_port_block
from tests.top.forgery import forge_as_system_1
from uav_model.mission import load_mission
from uav_model.signing_key import MAX_KEY_FILE_BYTES, signing_timestamp

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "tests" / "data" / "small_swap.yaml"
FORGE_S = 3.0
REFUSAL_WALL_S = 120  # bounds a refusal on a loaded machine; a free one refuses within seconds


def _key(tmp_path: Path, phrase: str) -> Path:
    path = tmp_path / f"{phrase.replace(' ', '_')}.key"
    path.write_text(phrase + "\n")
    return path


def _forge(port: int, seconds: float) -> int:
    """Forgeries as system 1, unsigned and signed with a wrong key by turns; the frames sent."""
    unsigned = mavlink.MAVLink(None, 1, 1)
    wrong = mavlink.MAVLink(None, 1, 1)
    wrong.signing.secret_key, wrong.signing.sign_outgoing = bytes(range(32)), True
    wrong.signing.timestamp = signing_timestamp() + 100_000
    return forge_as_system_1(port, SMALL, seconds, [unsigned, wrong])[1]


def _modes(run, name: str) -> list[str]:
    try:
        return run.telemetry.vehicle(name).modes
    except AssertionError:  # not heard on the GCS link yet
        return []


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_signed_flight_succeeds_and_frames_forged_in_flight_are_dropped_and_counted(companion, tmp_path):
    port_base = free_udp_port_block(2)
    run = companion.start(SMALL, "--no-land", "--signing-key", str(_key(tmp_path, "correct horse")),
                          "--port-base", str(port_base))
    deadline = time.monotonic() + 300.0  # bounds for a loaded machine; a free one flies in seconds
    while "OFFBOARD" not in _modes(run, "a"):
        assert run.process.poll() is None and time.monotonic() < deadline, run.wait(1).tail
        time.sleep(0.1)
    time.sleep(1.0)  # well into the flight
    forged = _forge(port_base, FORGE_S)
    result = run.wait(300)
    assert result.exit_code == 0, result.tail
    summary = result.summary
    assert summary["success"] is True, result.tail
    events = summary["live"]["link_events"]
    assert events["a"]["signing_refused"] >= forged, events
    assert events["a"]["signed_out"] > 100 and events["a"]["verified_in"] > 1000, events
    assert events["b"]["signed_out"] > 100 and "signing_refused" not in events["b"], events
    assert f"a: link: {events['a']['signing_refused']} frames dropped by the signing check" in result.stdout
    assert "someone else" not in result.stdout + result.stderr and "link_conflict" not in result.stdout
    # The forgeries never reached MAVSDK: no 5 km jump in the flown path, no HOLD in flight.
    speed = load_mission(SMALL).vehicle("a").speed_m_s
    a = summary["vehicles"]["a"]
    assert a["path_length_m"] <= 1.2 * speed * a["flight_time_s"] + 50.0, a
    # The stub signed and checked the whole flight and refused nothing the companion sent.
    stub_log = (result.out_dir / "sim_bridge.log").read_text()
    assert "MAVLink 2 signing on" in stub_log and "refused" not in stub_log, stub_log[-2000:]


def _refusal(run) -> str:
    assert run.exit_code == 2, run.tail
    (line,) = [ln for ln in run.stderr.splitlines() if ln.startswith("companion:")]
    assert "Traceback" not in run.stderr and "refused: vehicle 'a': signing: " in line and "nothing was armed" in line
    assert "offboard" not in line.lower()
    return line


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_disagreement_about_signing_is_refused_in_one_line(sitl, companion, tmp_path):
    key, other = str(_key(tmp_path, "correct horse")), str(_key(tmp_path, "battery staple"))
    signed = sitl(SMALL, extra=["--signing-key", key])
    started = time.monotonic()
    line = _refusal(companion(signed, "--no-certificate", timeout_s=REFUSAL_WALL_S))
    assert "signs its MAVLink frames and so refuses unsigned commands" in line and "--signing-key FILE" in line
    line = _refusal(companion(signed, "--no-certificate", "--signing-key", other, timeout_s=REFUSAL_WALL_S))
    assert "fail the signature check: the autopilot's key is not the one in --signing-key" in line
    assert "ARMED" not in " ".join(signed.vehicle("a").modes) and signed.process.poll() is None
    plain = sitl(SMALL)
    line = _refusal(companion(plain, "--no-certificate", "--signing-key", key, timeout_s=REFUSAL_WALL_S))
    assert "sends unsigned MAVLink frames but --signing-key is set" in line
    assert time.monotonic() - started < 3 * REFUSAL_WALL_S


def _companion(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "companion", "run", str(SMALL), "--no-certificate", *args],
                          capture_output=True, text=True, timeout=REFUSAL_WALL_S, env=env, cwd=ROOT)


def _bad_key(tmp_path: Path, name: str) -> Path:
    if name == "empty":
        (tmp_path / "empty.key").write_text("  \n")
    elif name == "huge":
        (tmp_path / "huge.key").write_bytes(b"x" * (1 << 20))
    return {"missing": tmp_path / "missing.key", "empty": tmp_path / "empty.key", "directory": tmp_path,
            "device": Path("/dev/zero"), "huge": tmp_path / "huge.key"}[name]


@pytest.mark.parametrize("name, why", [
    ("missing", "not a regular file"), ("empty", "empty"), ("directory", "not a regular file"),
    ("device", "not a regular file"), ("huge", f"larger than {MAX_KEY_FILE_BYTES} bytes"),
])
def test_a_bad_key_file_exits_2_in_one_line(tmp_path, name, why):
    path = _bad_key(tmp_path, name)
    proc = _companion("--signing-key", str(path))
    assert proc.returncode == 2, proc.stderr[-2000:]
    (line,) = proc.stderr.splitlines()
    assert line.startswith(f"companion: --signing-key {path}: {why}"), line
    assert proc.stdout == ""


@pytest.mark.parametrize("args, why", [
    (["--in-process"], "--signing-key: --in-process has no MAVLink link to sign"),
    (["--connect", "a=tcpout://127.0.0.1:5760", "--connect", "b=udpin://127.0.0.1:14541"],
     "--signing-key: a=tcpout://127.0.0.1:5760: the companion signs on udpin:// links only"),
])
def test_signing_where_there_is_no_link_to_sign_exits_2_in_one_line(tmp_path, args, why):
    proc = _companion("--signing-key", str(_key(tmp_path, "correct horse")), *args)
    assert proc.returncode == 2, proc.stderr[-2000:]
    (line,) = proc.stderr.splitlines()
    assert line.startswith(f"companion: {why}"), line


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_upload_signs_its_link_and_is_refused_in_one_line_without_the_key(sitl, companion, tmp_path):
    key = str(_key(tmp_path, "correct horse"))
    signed = sitl(SMALL, extra=["--signing-key", key])
    refused = companion.cli("upload", SMALL, *signed.connect_args(), timeout_s=REFUSAL_WALL_S)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    (line,) = refused.stderr.splitlines()
    assert "signs its MAVLink frames and so refuses unsigned commands" in line and "--signing-key FILE" in line
    result = companion.cli("upload", SMALL, *signed.connect_args(), "--signing-key", key, timeout_s=REFUSAL_WALL_S)
    assert result.returncode == 0, result.stdout + result.stderr
    # Read back over the signed link and compared by the companion (the GCS's link is unsigned: the
    # stub refuses its mission download).
    assert all(f"{n}: uploaded " in result.stdout and "read them back" in result.stdout for n in ("a", "b")), result.stdout
    assert not any(signed.vehicle("a").armed_history)
