"""pytest plugin: telemetry-driven scenario tests against the SITL stub and the companion.

Installed with the package (entry point ``pytest11: astar_bdwa``); docs/testing.md is the guide.
Three fixtures, all factories:

``sitl(mission_path, speedup=20, loss=0, latency_ms=0, blackout=(), seed=1, extra=())``
    starts ``sim-bridge`` for the mission on free UDP ports with a GCS-side recorder already
    listening, and returns a :class:`Sitl` once every vehicle is heard on both links.
``px4(mission_path, speedup=4, params={})``
    starts real PX4 SITL (SIH), one instance per vehicle at its start station, with the GCS
    recorder on PX4's port 14550, and returns a :class:`Px4Sitl` once every vehicle is heard.
    Skipped, saying how to enable it, unless ``PX4_SITL_DIR`` or ``--px4-dir`` names PX4.
``companion(target, *args, timeout_s=180)``
    runs ``companion run`` to the end and returns a :class:`CompanionRun`. ``target`` is a
    :class:`Sitl` or :class:`Px4Sitl` (the companion connects to it) or a mission path (the companion starts its
    embedded stub, whose GCS link the recorder hears: ``run.telemetry``).
    ``companion.start(...)`` returns a :class:`RunningCompanion` instead, to signal mid-flight.

Assertions read the vehicles' own telemetry as a GCS hears it (:class:`Telemetry`): arrival,
separation, clearance to the mission's TRUE obstacles, geofence, the mode sequence, the mission
stored on each vehicle, and :meth:`Telemetry.report` (SPEC §2 metrics from the shared
:mod:`companion.planning.metrics`, LOS metrics included).

Every process is started in its own session with a tag in its environment, which its children
inherit. Teardown, pass or fail, stops each process group (SIGTERM, then SIGKILL) and then every
tagged process left, so no orphan (MAVSDK servers, an embedded stub) outlives a test.

This module is what pytest loads; the harness lives in modules of one concern each:

    processes.py   tagged processes, stopped group by group at teardown
    recorder.py    the asyncio GCS-side recorder (one log per vehicle heard)
    telemetry.py   the recorder on a thread, and Telemetry: tracks, modes, traffic, waits, report()
    assertions.py  the assert_* methods Telemetry carries
    stub.py        Sitl and the ``sitl`` factory (a sim-bridge process)
    px4.py         Px4Sitl and the ``px4`` factory (companion.sitl.px4's PX4 instances)
    runs.py        CompanionRun, RunningCompanion and the ``companion`` factory
    fixtures.py    the fixtures
"""

from __future__ import annotations

from companion.testing.fixtures import companion, px4, pytest_addoption, pytest_configure, sitl
from companion.testing.px4 import Px4Factory, Px4Sitl
from companion.testing.runs import CompanionFactory, CompanionRun, RunningCompanion
from companion.testing.stub import Sitl, SitlFactory
from companion.testing.telemetry import BackgroundRecorder, Telemetry, TrafficSample

__all__ = ["BackgroundRecorder", "CompanionFactory", "CompanionRun", "Px4Factory", "Px4Sitl", "RunningCompanion", "Sitl",
           "SitlFactory", "Telemetry", "TrafficSample", "companion", "px4", "pytest_addoption", "pytest_configure", "sitl"]
