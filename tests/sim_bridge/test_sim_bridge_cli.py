"""``sim-bridge`` / ``python -m sim_bridge`` as a process: it serves, says so, and stops cleanly."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.testing import free_udp_port_block, free_udp_ports

MISSION_YAML = """
name: cli
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, system_id: 7}
  - {name: b, start: B, goal: A, system_id: 9}
"""


def run_cli(*args: str, timeout_s: float = 20.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sim_bridge", *args], capture_output=True, text=True,
                          timeout=timeout_s)


@pytest.mark.timeout(60)
def test_cli_serves_each_vehicle_on_its_port_and_stops_on_sigint(tmp_path: Path):
    mission = tmp_path / "cli.yaml"
    mission.write_text(MISSION_YAML)
    api0 = free_udp_port_block(2)
    (gcs,) = free_udp_ports(1)
    listeners = []
    for port in (api0, api0 + 1):  # the companion side listens (udpin); the vehicle sends first
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", port))
        s.settimeout(5.0)
        listeners.append(s)
    proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(mission), "--speedup", "4",
                             "--api-port-base", str(api0), "--gcs-port", str(gcs), "--tlog", str(tmp_path / "logs")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        banner = [proc.stdout.readline() for _ in range(5)]
        assert f"vehicle a: sysid 7 -> 127.0.0.1:{api0}" in banner[0]
        assert f"udpin://127.0.0.1:{api0 + 1}" in banner[1]
        assert "running at 4x" in banner[-1]
        parser = mavlink.MAVLink(None, 0, 0)
        for sock, sysid in zip(listeners, (7, 9)):
            msgs = parser.parse_buffer(sock.recvfrom(2048)[0]) or []
            assert msgs and all(m.get_srcSystem() == sysid for m in msgs)
        time.sleep(0.5)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0 and time.monotonic() - t0 < 3.0
        assert "Traceback" not in err and "stopped" in err
        assert len(list((tmp_path / "logs").glob("cli-*.tlog"))) == 1
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        for s in listeners:
            s.close()


@pytest.mark.timeout(60)
def test_cli_sigterm_stops_cleanly(tmp_path: Path):
    mission = tmp_path / "cli.yaml"
    mission.write_text(MISSION_YAML)
    (gcs, base) = free_udp_ports(2)
    proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(mission), "--api-port-base", str(base),
                             "--gcs-port", str(gcs)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        while "running at" not in proc.stdout.readline():
            pass
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0 and "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("args, message", [
    (["missing.yaml"], "sim-bridge: missing.yaml: file not found"),
    (["{mission}", "--speedup", "0"], "speedup 0.0: must be in [0.01, 1000]"),
    (["{mission}", "--loss", "2"], "loss 2.0: must be a probability in [0, 1]"),
    (["{mission}", "--blackout", "5"], "expected START:DURATION"),
    (["{mission}", "--gcs-port", "70000"], "70000 is not a UDP port"),
    (["{mission}", "--param", "COM_OBL_RC_ACT"], "expected NAME=VALUE"),
    (["{mission}", "--param", "NO_SUCH_PARAM=1"], "--param NO_SUCH_PARAM: unknown parameter"),
    (["{mission}", "--param", "COM_OBL_RC_ACT=9"], "--param COM_OBL_RC_ACT=9: outside [0, 7]"),
])
def test_cli_bad_input_is_one_clear_line(tmp_path: Path, args: list[str], message: str):
    mission = tmp_path / "cli.yaml"
    mission.write_text(MISSION_YAML)
    result = run_cli(*[a.replace("{mission}", str(mission)) for a in args])
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert result.stdout == ""
