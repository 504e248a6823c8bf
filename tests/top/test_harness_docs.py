"""docs/testing.md's first scenario, run exactly as a new user would: its mission and its test
copied out of the guide into an empty directory and run with a plain ``pytest`` there."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "testing.md"
# A fenced block whose info string names a file: ```yaml depot_swap.yaml
NAMED_BLOCK = re.compile(r"^```\w+ (\S+)\n(.*?)^```", re.MULTILINE | re.DOTALL)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def test_the_guides_example_passes_as_written(tmp_path, inner_pytest):
    files = dict(NAMED_BLOCK.findall(GUIDE.read_text()))
    assert {"depot_swap.yaml", "test_depot_swap.py"} <= set(files), sorted(files)
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    # The inner run's own timeout lets its fixtures clean up before ours would have to.
    code, out = inner_pytest("-o", "timeout=150", "test_depot_swap.py", timeout_s=200)
    assert code == 0, out[-4000:]
    assert "1 passed" in out, out[-2000:]
