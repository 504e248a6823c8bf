"""Fixtures shared by the scenario tests that call the companion's CLI in this process."""

from __future__ import annotations

import logging

import pytest


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
