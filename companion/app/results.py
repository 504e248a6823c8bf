"""Where a run's results go, and what is kept when the disk says no.

    prepare_output(dir, reserve=True)      before anything flies: create, write-probe, reserve space
    save_results(dir, summary, artefacts)  after the verdict: summary.json first, then the rest

``--out`` is checked before the flight by writing into it (``OutputNotWritable``: the CLI's one
line and exit 2). A run that writes logs as it flies also reserves :data:`RESERVE_BYTES` there:
the logs may fill the disk, and the reserve is given back just before summary.json is written,
so the verdict survives a full disk. Every file is written to a temporary name and renamed, so a
reader never sees a half-written summary.json or a 0-byte trajectory.png. A file that cannot be
written is named in :class:`SaveReport` with the reason; the others are still written.
"""

from __future__ import annotations

import errno
import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

RESERVE_NAME = ".companion-reserve"
RESERVE_BYTES = 1 << 20  # summary.json is a few KB, trajectory.png ~200 KB
SUMMARY_NAME = "summary.json"


class OutputNotWritable(Exception):
    """``--out`` cannot be created or written: one line naming the directory and the reason."""


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc)


def prepare_output(path: Path, *, reserve: bool = False) -> Path:
    """Create ``path`` and prove it writable (a probe file, or the space reserve when ``reserve``)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputNotWritable(f"--out {path}: cannot create the directory ({_why(exc)})") from None
    probe = path / (RESERVE_NAME if reserve else f".companion-probe-{os.getpid()}")
    size = RESERVE_BYTES if reserve else 1
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            try:
                os.posix_fallocate(fd, 0, size)
            except OSError as exc:
                if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                    raise
                os.write(fd, b"\0" * size)
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        _unlink_quietly(probe)
        room = f" (reserving {RESERVE_BYTES >> 10} KiB for the results)" if reserve else ""
        raise OutputNotWritable(f"--out {path}: cannot write there{room} ({_why(exc)})") from None
    if not reserve:
        _unlink_quietly(probe)
    return path


def _unlink_quietly(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass  # read-only or gone: nothing of ours is left there


def release_reserve(path: Path) -> None:
    """Give back the space :func:`prepare_output` set aside (done by :func:`save_results` too)."""
    _unlink_quietly(path / RESERVE_NAME)


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` to a temporary file beside ``path`` (same suffix), synced, then renamed over
    ``path``; on any error the temporary file is removed and ``path`` is left as it was."""
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


def write_json_atomic(path: Path, doc: Any) -> None:
    text = json.dumps(doc, indent=2) + "\n"
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


@dataclass
class SaveReport:
    """What :func:`save_results` wrote, what it could not (name, reason), and what was lost before."""

    out_dir: Path
    written: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # e.g. a log truncated in flight

    @property
    def complete(self) -> bool:
        return not self.failed and not self.problems

    def line(self) -> str:
        """One line: every file written, or what was kept and what was not (and why)."""
        kept = ", ".join(self.written) or "nothing"
        if self.complete:
            return f"wrote {self.out_dir}/: {kept}"
        lost = [f"{name} ({why})" for name, why in self.failed] + self.problems
        return f"companion: output in {self.out_dir}: kept {kept}; incomplete: {'; '.join(lost)}"


def save_results(out_dir: Path, summary: dict[str, Any],
                 artefacts: Sequence[tuple[str, Callable[[Path], None]]] = (),
                 problems: Sequence[str] = ()) -> SaveReport:
    """summary.json first (after giving back the space reserve), then each artefact ``(file
    name, writer)``. The summary lists the output problems (``outputs``); it is written again as
    soon as an artefact fails, so that it names that failure too."""
    report = SaveReport(out_dir, problems=list(problems))
    if not out_dir.is_dir():
        report.problems.append("the output folder was removed during the run (recreated; its logs are lost)")
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            report.failed.append((SUMMARY_NAME, f"cannot recreate {out_dir}: {_why(exc)}"))
            report.failed += [(name, "no folder") for name, _ in artefacts]
            return report
    release_reserve(out_dir)

    def write_summary(first: bool = True) -> bool:
        doc = dict(summary, outputs={"complete": report.complete, "incomplete": [
            f"{name}: {why}" for name, why in report.failed if name != SUMMARY_NAME] + report.problems})
        try:
            write_json_atomic(out_dir / SUMMARY_NAME, doc)
            return True
        except OSError as exc:
            if first:
                report.failed.append((SUMMARY_NAME, _why(exc)))
            return False

    summary_ok = write_summary()
    for name, writer in artefacts:
        try:
            write_atomic(out_dir / name, writer)
            report.written.append(name)
        except OSError as exc:
            report.failed.append((name, _why(exc)))
            if summary_ok:  # at once, while the failed file's space is free again; if it cannot, the last one stands
                write_summary(first=False)
    if summary_ok:
        report.written.insert(0, SUMMARY_NAME)
    return report


class QuietFileHandler(logging.FileHandler):
    """A log file that stops, recording why, when the disk refuses a write (the stock handler
    prints a traceback to stderr on every record)."""

    def __init__(self, path: Path):
        super().__init__(path, encoding="utf-8")
        self.problem: str | None = None

    def handleError(self, record: logging.LogRecord) -> None:  # noqa: N802 - logging's name
        if self.problem is None:
            self.problem = f"{Path(self.baseFilename).name}: stopped ({_log_error()})"
        try:
            self.close()
        except OSError:
            pass

    def emit(self, record: logging.LogRecord) -> None:
        if self.problem is None:
            super().emit(record)


def _log_error() -> str:
    import sys
    exc = sys.exc_info()[1]
    return _why(exc) if isinstance(exc, OSError) else str(exc)
