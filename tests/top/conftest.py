"""Fixtures shared by the top layer's tests: the companion's CLI in this process, and pytest in a child."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from companion.cli import main


@pytest.fixture
def companion_logger():
    """``companion run`` sends the companion's log to a file in --out: undo that afterwards."""
    logger = logging.getLogger("companion")
    saved = (list(logger.handlers), logger.level, logger.propagate)
    yield
    for handler in logger.handlers[:]:
        if handler not in saved[0]:
            logger.removeHandler(handler)
            handler.close()
    logger.setLevel(saved[1])
    logger.propagate = saved[2]


@dataclass(frozen=True)
class InProcessRun:
    """A finished ``companion run --in-process``: what it printed, its summary.json, its --out."""

    stdout: str
    summary: dict
    out_dir: Path


@pytest.fixture
def run_in_process(tmp_path, capsys, companion_logger) -> Callable[..., InProcessRun]:
    """``run_in_process(mission, *args)``: ``companion run MISSION --in-process *args`` in this
    process, into ``tmp_path/run``; fails unless it exits 0."""
    def run(mission: str | os.PathLike, *args: str) -> InProcessRun:
        out = tmp_path / "run"
        code = main(["run", str(mission), "--in-process", *args, "--out", str(out)])
        stdout = capsys.readouterr().out
        assert code == 0, stdout[-3000:]
        return InProcessRun(stdout, json.loads((out / "summary.json").read_text()), out)
    return run


@pytest.fixture
def inner_pytest(tmp_path) -> Callable[..., tuple[int, str]]:
    """``inner_pytest(*args, timeout_s=..., env={})``: pytest in a child process, in ``tmp_path``
    (write the test files there first), in its own session: (exit code, output). A child that
    overruns ``timeout_s`` is killed with its whole process group."""
    def run(*args: str, timeout_s: float, env: dict[str, str] | None = None) -> tuple[int, str]:
        child_env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
        child_env.update(env or {})
        proc = subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
                                cwd=tmp_path, env=child_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout_s)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        return proc.returncode, out
    return run
