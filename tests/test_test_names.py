"""Test modules have unique file names: pytest's default import mode imports each one as a
top-level module named by its file, so a second ``test_x.py`` anywhere under tests/ fails to
collect ("import file mismatch") and the README's test command fails."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_no_two_test_modules_share_a_file_name():
    names = Counter(p.name for p in TESTS.rglob("*.py") if p.name != "conftest.py" and p.name != "__init__.py")
    assert [n for n, k in names.items() if k > 1] == []
