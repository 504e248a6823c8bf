"""Whom the stub obeys, over real UDP: an allowlist of system ids, and MAVLink 2 signing.

A raw pymavlink client stands where the companion would (it owns the vehicle's API port) and
sends COMPONENT_ARM_DISARM: a refused sender gets no ACK and the vehicle stays disarmed; an
allowed (or correctly signed) one arms it.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import socket
import subprocess
import sys
import time
from dataclasses import dataclass

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.admission import parse_sysids
from uav_model.signing_key import SigningKeyError, load_signing_key, signing_timestamp
from sim_bridge.bridge import SimOptions
from sim_bridge.testing import stub_on_free_ports
from uav_model.mission import parse_mission

MISSION_TEXT = """
name: admission
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 5}
"""
MISSION = parse_mission(MISSION_TEXT, "admission.yaml")
KEY = hashlib.sha256(b"correct horse").digest()


class Client:
    """A ground station on vehicle 0's API port: sends from it, reads the stub's frames on it."""

    def __init__(self, sim, sysid: int, key: bytes | None = None, verify_key: bytes | None = None,
                 timestamp: int | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", sim.options.api_port(0)))
        self.sock.setblocking(False)
        self.stub = sim.api_address(0)
        self.enc = mavlink.MAVLink(None, sysid, 190)
        if key is not None:
            self.enc.signing.secret_key, self.enc.signing.sign_outgoing = key, True
            self.enc.signing.timestamp = signing_timestamp() if timestamp is None else timestamp
        self.dec = mavlink.MAVLink(None, 0, 0)
        self.dec.robust_parsing = True
        if verify_key is not None:
            self.dec.signing.secret_key = verify_key
            self.dec.signing.timestamp = signing_timestamp()
        self.frames: list = []

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.sock.close()

    def arm(self) -> None:
        msg = self.enc.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        self.sock.sendto(msg.pack(self.enc), self.stub)

    async def collect(self, seconds: float) -> list:
        loop = asyncio.get_running_loop()
        end = time.monotonic() + seconds
        got = []
        while time.monotonic() < end:
            try:
                async with asyncio.timeout(max(end - time.monotonic(), 0.01)):
                    data = await loop.sock_recv(self.sock, 4096)
            except TimeoutError:
                break
            got += [(data, m) for m in (self.dec.parse_buffer(data) or [])]
        return got


def _acks(frames) -> list:
    return [m for _, m in frames if m.get_type() == "COMMAND_ACK" and m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM]


@dataclass
class ArmAttempt:
    """One client's COMPONENT_ARM_DISARM: the ACKs it got, whether the vehicle was armed after it,
    the frames it heard in ``listen_s`` after that, and its decoder's signature counts."""

    acks: list
    armed: bool
    frames: list
    signing: object


@pytest.fixture
def arm_attempts():
    """``arm_attempts(options, clients, **stub)``: a stub of MISSION on free ports (no GCS link), then
    each client of ``clients`` (Client keyword arguments, plus ``listen_s``) in turn on vehicle 0's
    API port tries to arm it. Returns the attempts in order and the stub's admission record."""

    def run(options: SimOptions, clients: list[dict], **stub) -> tuple[list[ArmAttempt], object]:
        async def scenario():
            attempts = []
            async with stub_on_free_ports(MISSION, options, gcs=False, **stub) as sim:
                for spec in clients:
                    spec = dict(spec)
                    listen_s = spec.pop("listen_s", 0.0)
                    with Client(sim, **spec) as client:
                        client.arm()
                        acks = _acks(await client.collect(1.5))
                        armed = sim.vehicle(0).armed
                        frames = await client.collect(listen_s) if listen_s else []
                        attempts.append(ArmAttempt(acks, armed, frames, client.dec.signing))
                return attempts, sim.admission
        return asyncio.run(scenario())

    return run


@pytest.mark.timeout(60)
def test_a_foreign_system_id_is_refused_with_a_log_line_and_no_effect(caplog, arm_attempts):
    with caplog.at_level(logging.WARNING, logger="sim_bridge.admission"):
        (intruder, owner), admission = arm_attempts(SimOptions(speedup=4.0), [{"sysid": 250}, {"sysid": 245}],
                                                    allow_sysids=frozenset({245}))
    assert intruder.acks == [] and intruder.armed is False
    assert [a.result for a in owner.acks] == [mavlink.MAV_RESULT_ACCEPTED] and owner.armed is True
    assert admission.refused >= 1
    assert any("refused COMMAND_LONG from system 250" in r.message and "not in --allow-sysid 245" in r.message
               for r in caplog.records), caplog.text


@pytest.mark.timeout(60)
def test_a_stub_with_a_key_signs_its_frames_and_obeys_only_signed_commands(caplog, arm_attempts):
    wrong = hashlib.sha256(b"wrong").digest()
    with caplog.at_level(logging.WARNING, logger="sim_bridge.admission"):
        (unsigned, other, signed), _ = arm_attempts(SimOptions(speedup=4.0, signing_key=KEY), [
            {"sysid": 245, "verify_key": KEY},
            # Another key, and a far-future timestamp on the stream the owner uses next: it must not lock the owner out.
            {"sysid": 245, "key": wrong, "verify_key": KEY, "timestamp": (1 << 48) - 10},
            {"sysid": 245, "key": KEY, "verify_key": KEY, "listen_s": 0.5}])
    assert (unsigned.acks, unsigned.armed) == ([], False)
    assert (other.acks, other.armed) == ([], False)
    assert [a.result for a in signed.acks] == [mavlink.MAV_RESULT_ACCEPTED] and signed.armed is True
    # Every frame the stub sent is MAVLink 2 with the signed flag, and verifies with the key.
    assert signed.frames and all(data[0] == 0xFD and data[2] & 0x01 for data, _ in signed.frames)
    assert signed.signing.goodsig_count > 0 and signed.signing.badsig_count == 0
    assert any("unsigned or not signed with --signing-key" in r.message for r in caplog.records), caplog.text


def test_key_files_raw_hex_and_passphrase(tmp_path):
    raw = tmp_path / "raw.key"
    raw.write_bytes(KEY)
    hexed = tmp_path / "hex.key"
    hexed.write_text(KEY.hex() + "\n")
    phrase = tmp_path / "phrase.key"
    phrase.write_text("correct horse\n")
    assert load_signing_key(raw) == load_signing_key(hexed) == load_signing_key(phrase) == KEY
    empty = tmp_path / "empty.key"
    empty.write_text("  \n")
    for bad, why in ((empty, "empty"), (tmp_path / "missing.key", "not a regular file"), (tmp_path, "not a regular")):
        with pytest.raises(SigningKeyError, match=why):
            load_signing_key(bad)
    assert parse_sysids("255, 245") == {255, 245}
    with pytest.raises(ValueError, match="'0' is not a system id"):
        parse_sysids("255,0")


@pytest.mark.parametrize("args, message", [
    (["--signing-key", "/nonexistent/key"], "sim-bridge: --signing-key /nonexistent/key: not a regular file"),
    (["--allow-sysid", "255,x"], "sim-bridge: --allow-sysid '255,x': 'x' is not a system id (1..255)"),
])
def test_sim_bridge_refuses_a_bad_key_or_allowlist_in_one_line(args, message, tmp_path):
    mission = tmp_path / "m.yaml"
    mission.write_text(MISSION_TEXT)
    proc = subprocess.run([sys.executable, "-m", "sim_bridge", str(mission), *args], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and proc.stderr.strip() == message, proc.stderr

