"""Results are never lost: a read-only --out, a folder removed in flight and a full disk, each
on a real file system (a small tmpfs in a private mount namespace), with the real CLI in a child.

Each case must print the verdict, keep summary.json whole (or name why it could not), and say in
one line what was kept; a flight's exit code stays the flight's.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "missions" / "small_reference.yaml"
pytestmark = pytest.mark.timeout(900)  # flights on a loaded machine; each takes 5-40 s on a free one
FULL_TMPFS = "1100k"  # the 1 MiB reserve fits, and ~70 KB more: the flight's logs fill the rest


def _private_mounts() -> bool:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", "-mn", "true"], capture_output=True).returncode == 0


needs_mounts = pytest.mark.skipif(not _private_mounts(), reason="needs root and unshare -mn (a private tmpfs)")


def _companion(*args: str) -> str:
    return " ".join(shlex.quote(a) for a in (sys.executable, "-m", "companion", *args))


def _in_namespace(script: str, timeout_s: float = 600.0) -> subprocess.CompletedProcess:
    """``script`` (sh) in private mount and network namespaces: its tmpfs and ports are its own."""
    return subprocess.run(["unshare", "-mn", "sh", "-c", "ip link set lo up 2>/dev/null; " + script],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)


def _no_traceback(proc: subprocess.CompletedProcess) -> None:
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-3000:]


def _one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return lines[0]


@needs_mounts
@pytest.mark.parametrize("command", [["simulate"], ["run", "--in-process"]], ids=["simulate", "run"])
@pytest.mark.parametrize("existing", [False, True], ids=["new-dir", "existing-dir"])
def test_read_only_out_is_refused_before_anything_flies(tmp_path, command, existing):
    mnt = tmp_path / "ro"
    mnt.mkdir()
    out = mnt / "out"
    make = f"mkdir {shlex.quote(str(out))} && mount -o remount,ro {shlex.quote(str(mnt))} && " if existing else \
        f"mount -o remount,ro {shlex.quote(str(mnt))} && "
    proc = _in_namespace(f"mount -t tmpfs -o size=1m tmpfs {shlex.quote(str(mnt))} && {make}"
                         + _companion(command[0], str(SMALL), *command[1:], "--out", str(out)), timeout_s=120)
    _no_traceback(proc)
    assert proc.returncode == 2, proc.stderr
    line = _one_line(proc.stderr)
    assert line.startswith(f"companion: --out {out}: ") and "Read-only file system" in line, line
    assert "SUCCESS" not in proc.stdout and "FAILED" not in proc.stdout  # refused before flying


@needs_mounts
def test_simulate_on_a_full_disk_keeps_the_summary_and_names_the_picture(tmp_path):
    mnt, copy = tmp_path / "full", tmp_path / "copy"
    mnt.mkdir()
    out = mnt / "out"
    proc = _in_namespace(
        f"mount -t tmpfs -o size=64k tmpfs {mnt} && mkdir {out} && (head -c 40000 /dev/zero > {mnt}/filler); "
        + _companion("simulate", str(SMALL), "--out", str(out)) + f"; rc=$?; cp -a {out} {copy}; exit $rc")
    _no_traceback(proc)
    assert proc.returncode == 0, proc.stderr
    assert "small_reference [astar-bdwa]: SUCCESS" in proc.stdout
    line = _one_line(proc.stderr)
    assert "kept summary.json; incomplete: trajectory.png (No space left on device)" in line, line
    summary = json.loads((copy / "summary.json").read_text())
    assert summary["success"] is True
    # flight.csv, written after the picture, may find the disk full too: whatever failed is named
    assert summary["outputs"]["complete"] is False
    assert summary["outputs"]["incomplete"][0] == "trajectory.png: No space left on device", summary["outputs"]
    assert sorted(p.name for p in copy.iterdir()) == ["summary.json"]  # no 0-byte picture, no temp file


@needs_mounts
def test_run_on_a_full_disk_reports_every_truncated_log_and_keeps_the_results(tmp_path):
    """The embedded stub over real UDP: its .tlog and flight.csv fill the disk in flight; the
    verdict, summary.json and trajectory.png are still written from the reserve."""
    mnt, copy = tmp_path / "full", tmp_path / "copy"
    mnt.mkdir()
    out = mnt / "out"
    proc = _in_namespace(
        f"mount -t tmpfs -o size={FULL_TMPFS} tmpfs {mnt} && "
        + _companion("run", str(SMALL), "--speedup", "10", "--out", str(out)) + f"; rc=$?; cp -a {out} {copy}; exit $rc")
    _no_traceback(proc)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr
    assert "run: SUCCESS" in proc.stdout
    line = _one_line(proc.stderr)
    assert line.startswith(f"companion: output in {out}: kept summary.json, trajectory.png; incomplete: "), line
    assert ".tlog truncated: No space left on device" in line and "flight.csv (No space left on device" in line
    summary = json.loads((copy / "summary.json").read_text())
    assert summary["success"] is True and summary["outputs"]["complete"] is False
    assert any(".tlog truncated" in p for p in summary["outputs"]["incomplete"])
    assert (copy / "trajectory.png").stat().st_size > 10_000
    assert not [p.name for p in copy.iterdir() if "partial" in p.name or p.name.startswith(".companion")]


def test_out_folder_removed_in_flight_still_gives_the_verdict_and_the_summary(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "companion", "run", str(SMALL), "--in-process", "--speedup", "20",
                             "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300.0  # a bound for a loaded machine; a free one is in flight in ~5 s
        flight = out / "flight.csv"
        while time.monotonic() < deadline and proc.poll() is None:
            if flight.exists() and flight.read_text().count("\n") > 20:  # in flight: ticks logged
                break
            time.sleep(0.1)
        assert proc.poll() is None, "the flight ended before the folder could be removed"
        assert flight.exists(), "not in flight after 300 s"
        shutil.rmtree(out)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "Traceback" not in stdout + stderr, stderr[-3000:]
    assert proc.returncode == 0, stderr
    assert "run: SUCCESS" in stdout
    line = _one_line(stderr)
    assert "kept summary.json, trajectory.png" in line and "removed during the run" in line, line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"] is True and summary["outputs"]["complete"] is False
