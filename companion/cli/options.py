"""Options that several ``companion`` subcommands share, and the checks behind them.

Each check raises :class:`companion.cli.errors.BadInput` (exit 2, one line) for a value that
cannot be used.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import functools
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from companion.app.flight_plan import prepare
from companion.app.results import OutputNotWritable, QuietFileHandler, prepare_output
from companion.cli.errors import BadInput, bad_input
from companion.planning.budget import BudgetSpent
from companion.vehicle.link_probe import udpin_port
from uav_model.mission import VARIANTS, Mission, MissionError, load_mission
from uav_model.plant import Plant
from uav_model.signing_key import SigningKeyError, load_signing_key

if TYPE_CHECKING:
    from companion.app.flight_plan import FlightPlan

log = logging.getLogger("companion")

def output_dir(path: Path, *, reserve: bool = False) -> Path:
    """``--out``, created if need be and proved writable (with ``reserve``: the space the results
    need is set aside while logs are written; see companion.app.results); BadInput when it cannot be."""
    try:
        return prepare_output(path, reserve=reserve)
    except OutputNotWritable as exc:
        raise BadInput(str(exc)) from None


def add_variant_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--variant", choices=VARIANTS, default=None, help="planner variant (default: the mission's)")


def add_plant_option(parser: argparse.ArgumentParser, live: bool = False) -> None:
    more = ("; with --sim px4 multicopter, and give multicopter with --connect to a real PX4: the planner's "
            "margins from the fence and its tracking lag are the plant's") if live else ""
    parser.add_argument("--plant", choices=[p.value for p in Plant], default=None,
                        help="the vehicles' dynamics (default: the mission's); unicycle is the paper's ideal vehicle, "
                             f"multicopter the PX4-like one{more}")


def with_plant(mission: Mission, plant: str | None) -> Mission:
    """The mission flown with ``--plant`` when one was given, else as written."""
    return mission if plant is None else dataclasses.replace(mission, plant=Plant(plant))


def plant_flown(args: argparse.Namespace) -> str | None:
    """``--plant`` when given; a multicopter on PX4 SITL (SIH flies a quadrotor, whatever the file says)."""
    given = getattr(args, "plant", None)
    if given is None and getattr(args, "sim", None) == "px4":
        return Plant.MULTICOPTER.value
    return given


def add_no_fence_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-fence", action="store_true",
                        help="do not upload the geofence (area as inclusion, inflated static obstacles as exclusions) "
                             "before arming: for autopilots without fence support")


def connections(plan: FlightPlan, pairs: list[tuple[str, str]]) -> dict[str, str]:
    """``--connect NAME=URL`` pairs as one URL per mission vehicle; BadInput for unknown, repeated or missing names."""
    names = [v.name for v in plan.mission.vehicles]
    out: dict[str, str] = {}
    for name, url in pairs:
        if name not in names:
            raise BadInput(f"--connect {name}=...: the mission has no vehicle {name!r} (vehicles: {', '.join(names)})")
        if name in out:
            raise BadInput(f"--connect {name}=... given twice")
        out[name] = url
    missing = [n for n in names if n not in out]
    if missing:
        raise BadInput(f"--connect missing for vehicle(s) {', '.join(missing)}: give one NAME=URL per vehicle")
    return out


def quiet_mavsdk(out_dir: Path | None) -> QuietFileHandler | None:
    """MAVSDK's own log goes to the companion's logger (a file with --out), not the terminal.
    Returns the file's handler, which records why it stopped if the disk refused it."""
    from mavsdk.logging import LogLevel, log_subscribe
    mav_log = logging.getLogger("companion.mavsdk")
    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO,
              LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}

    def forward(level, message, file, line) -> bool:
        mav_log.log(levels.get(level, logging.INFO), "%s", message)
        return True  # suppress MAVSDK's own printing
    log_subscribe(forward)
    root = logging.getLogger("companion")
    root.setLevel(logging.DEBUG)
    root.propagate = False
    if out_dir is None:
        return None
    handler = QuietFileHandler(out_dir / "companion.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    return handler


CERTIFICATE_BUDGET_S = 20.0  # CPU s: with imports and loading, a mission at the schema's limits validates in < 30 s


def add_certificate_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-certificate", action="store_true",
                        help="skip the occlusion certificate (whether the sight line can be kept blocked)")
    parser.add_argument("--certificate-budget", type=_seconds, default=CERTIFICATE_BUDGET_S, metavar="S",
                        help=f"CPU seconds the certificate may take before it says 'undecided within budget' "
                             f"(default {CERTIFICATE_BUDGET_S:g})")


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: must be a positive number of seconds")
    return value


def with_certificate_options(plan: FlightPlan, args: argparse.Namespace) -> FlightPlan:
    """The plan with ``--no-certificate`` / ``--certificate-budget`` applied (when the command has them)."""
    if not hasattr(args, "no_certificate"):
        return plan
    return dataclasses.replace(plan, with_certificate=not args.no_certificate,
                               certificate_budget=SecondsBudget(args.certificate_budget, "occlusion certificate"))


class SecondsBudget:
    """A work budget (:mod:`companion.planning.budget`) of seconds of this process's CPU time
    (other processes' load does not change the verdict), counted from the first unit spent, that
    shows progress on stderr every ``every_s`` of them."""

    def __init__(self, seconds: float, what: str, every_s: float = 5.0,
                 clock: Callable[[], float] = time.process_time):
        self.seconds, self.what, self.every_s, self.clock = seconds, what, every_s, clock
        self.units = 0
        self.started: float | None = None
        self._next_report = math.inf

    def spend(self, units: int = 1) -> None:
        now = self.clock()
        if self.started is None:
            self.started, self._next_report = now, now + self.every_s
        self.units += units
        if now - self.started > self.seconds:
            raise BudgetSpent(f"{self.seconds:g} s budget spent")
        if now >= self._next_report:
            self._next_report += self.every_s
            print(f"{self.what}: {now - self.started:.0f} s of at most {self.seconds:g} CPU s, {self.units} work units "
                  f"(--certificate-budget S to change, --no-certificate to skip)", file=sys.stderr, flush=True)


def connect_pair(text: str) -> tuple[str, str]:
    """``--connect NAME=URL`` as (name, MAVSDK URL)."""
    name, sep, url = text.partition("=")
    if not sep or not name or not url:
        raise argparse.ArgumentTypeError(f"--connect {text!r}: expected NAME=URL, e.g. a=udpin://0.0.0.0:14540")
    if "://" not in url:
        raise argparse.ArgumentTypeError(f"--connect {text!r}: {url!r} is not a MAVSDK URL (udpin://HOST:PORT, "
                                         "udpout://, tcpout://, serial://DEV:BAUD)")
    return name, url


def positive(text: str) -> float:
    """A finite number above zero (an argparse type)."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: must be a positive number")
    return value


def planned(handler: Callable[[argparse.Namespace, FlightPlan], int]) -> Callable[[argparse.Namespace], int]:
    """A subcommand on the mission's plan: a bad file or an unreachable goal exits 2 before it starts."""
    @functools.wraps(handler)
    def with_plan(args: argparse.Namespace) -> int:
        try:
            plan = prepare(with_plant(load_mission(args.mission), plant_flown(args)), args.variant)
            plan = with_certificate_options(dataclasses.replace(plan, geofence=not getattr(args, "no_fence", False)), args)
        except MissionError as exc:
            return bad_input(exc)
        return handler(args, plan)
    return with_plan


def printer(started: float):
    """A progress line with the wall seconds since ``started``, printed and logged."""
    def report(line: str) -> None:
        print(f"[{time.monotonic() - started:6.1f}s] {line}", flush=True)
        log.info("%s", line)
    return report


def add_signing_key_option(parser: argparse.ArgumentParser, more: str = "") -> None:
    parser.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                        help="MAVLink 2 signing: the link guard signs every frame MAVSDK sends and drops unsigned or "
                             f"badly signed frames from the autopilot (udpin:// links{more}). FILE: 32 bytes, 64 hex "
                             "digits or a passphrase (docs/companion.md, 'Signing')")


def signing_key(args: argparse.Namespace, conns: dict[str, str]) -> bytes | None:
    """The key of --signing-key; BadInput on a bad file, or for a link the guard cannot sign."""
    if args.signing_key is None:
        return None
    unsignable = [f"{n}={u}" for n, u in conns.items() if udpin_port(u) is None]
    if unsignable:
        raise BadInput(f"--signing-key: {', '.join(unsignable)}: the companion signs on udpin:// links only "
                       "(the UDP ports its link guard holds)")
    try:
        return load_signing_key(args.signing_key)
    except SigningKeyError as exc:
        raise BadInput(str(exc)) from None
