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

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim_bridge.admission import SigningKeyError, load_signing_key, parse_sysids, signing_timestamp
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

    def __init__(self, sim, sysid: int, key: bytes | None = None, verify_key: bytes | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", sim.options.api_port(0)))
        self.sock.setblocking(False)
        self.stub = sim.api_address(0)
        self.enc = mavlink.MAVLink(None, sysid, 190)
        if key is not None:
            self.enc.signing.secret_key, self.enc.signing.sign_outgoing = key, True
            self.enc.signing.timestamp = signing_timestamp()
        self.dec = mavlink.MAVLink(None, 0, 0)
        self.dec.robust_parsing = True
        if verify_key is not None:
            self.dec.signing.secret_key = verify_key
            self.dec.signing.timestamp = signing_timestamp()
        self.frames: list = []

    def close(self) -> None:
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


async def _arm_attempt(client: Client) -> list:
    client.arm()
    return _acks(await client.collect(1.5))


@pytest.mark.timeout(60)
def test_a_foreign_system_id_is_refused_with_a_log_line_and_no_effect(caplog):
    async def scenario():
        async with stub_on_free_ports(MISSION, SimOptions(speedup=4.0), allow_sysids=frozenset({245}),
                                      gcs=False) as sim:
            intruder = Client(sim, sysid=250)
            try:
                refused = await _arm_attempt(intruder)
                armed_by_intruder = sim.vehicle(0).armed
            finally:
                intruder.close()
            owner = Client(sim, sysid=245)
            try:
                accepted = await _arm_attempt(owner)
            finally:
                owner.close()
            return refused, armed_by_intruder, accepted, sim.vehicle(0).armed, sim.admission.refused

    with caplog.at_level(logging.WARNING, logger="sim_bridge.admission"):
        refused, armed_by_intruder, accepted, armed, count = asyncio.run(scenario())
    assert refused == [] and armed_by_intruder is False
    assert [a.result for a in accepted] == [mavlink.MAV_RESULT_ACCEPTED] and armed is True
    assert count >= 1
    assert any("refused COMMAND_LONG from system 250" in r.message and "not in --allow-sysid 245" in r.message
               for r in caplog.records), caplog.text


@pytest.mark.timeout(60)
def test_a_stub_with_a_key_signs_its_frames_and_obeys_only_signed_commands(caplog):
    async def scenario():
        async with stub_on_free_ports(MISSION, SimOptions(speedup=4.0, signing_key=KEY), gcs=False) as sim:
            results = {}
            for name, key in (("unsigned", None), ("other key", hashlib.sha256(b"wrong").digest())):
                c = Client(sim, sysid=245, key=key, verify_key=KEY)
                try:
                    results[name] = (await _arm_attempt(c), sim.vehicle(0).armed)
                finally:
                    c.close()
            c = Client(sim, sysid=245, key=KEY, verify_key=KEY)
            try:
                results["signed"] = (await _arm_attempt(c), sim.vehicle(0).armed)
                frames = await c.collect(0.5)
            finally:
                c.close()
            return results, frames, c.dec.signing

    with caplog.at_level(logging.WARNING, logger="sim_bridge.admission"):
        results, frames, verified = asyncio.run(scenario())
    assert results["unsigned"] == ([], False)
    assert results["other key"] == ([], False)
    acks, armed = results["signed"]
    assert [a.result for a in acks] == [mavlink.MAV_RESULT_ACCEPTED] and armed is True
    # Every frame the stub sent is MAVLink 2 with the signed flag, and verifies with the key.
    assert frames and all(data[0] == 0xFD and data[2] & 0x01 for data, _ in frames)
    assert verified.goodsig_count > 0 and verified.badsig_count == 0
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

