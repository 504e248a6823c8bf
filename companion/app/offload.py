"""Seconds of planning off the event loop: in a child process, so that neither the loop nor the GIL stalls.

    result = await in_child_process(function, *args)   # a module-level function, picklable arguments

A worker thread would still take the GIL from the loop and from MAVSDK's callback thread (PX4
streams hundreds of messages a second: MAVSDK then drops them, "a subscriber is not keeping up"),
and the event loop's backlog would arrive afterwards as one burst. A child process costs its
start-up (a second or two of imports) and nothing while it runs. Cancelling the wait kills the child.

Run as ``python -m companion.app.offload``: it reads one pickled ``(function, args)`` on stdin and
writes the pickled ``(ok, result-or-exception)`` on stdout. Only this module's parent speaks to it.
"""

from __future__ import annotations

import asyncio
import os
import pickle
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")

_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])  # the directory holding ``companion``


class ChildProcessFailed(RuntimeError):
    """The child died without an answer (killed, out of memory, an import error): its stderr tail."""


async def in_child_process(function: Callable[..., T], *args: object) -> T:
    """``function(*args)`` in a fresh Python process; its exception is raised here."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([_PACKAGE_ROOT, *filter(None, [env.get("PYTHONPATH")])])
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion.app.offload", stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env)
    try:
        out, err = await proc.communicate(pickle.dumps((function, args)))
    except BaseException:  # cancelled (the flight was stopped) or the loop is closing: no orphan
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        raise
    if proc.returncode != 0 or not out:
        tail = err.decode(errors="replace").strip().splitlines()[-3:]
        raise ChildProcessFailed(f"{getattr(function, '__name__', function)} in a child process exited "
                                 f"{proc.returncode}: {' / '.join(tail) or 'no output'}")
    ok, value = pickle.loads(out)
    if not ok:
        raise value
    return value


def _serve() -> int:
    function, args = pickle.loads(sys.stdin.buffer.read())
    try:
        answer = (True, function(*args))
    except Exception as exc:  # handed to the parent, which raises it
        answer = (False, exc)
    sys.stdout.buffer.write(pickle.dumps(answer))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(_serve())
