"""Run the companion's event loop to the end, and leave the process without waiting for ever.

    result = run_bounded(main())          # asyncio.run, with a bounded wait for worker threads
    leave(code)                           # exit now if a worker thread is still blocked

MAVSDK's asyncio API runs its blocking calls (parameters, commands, shutting an instance down) on
the loop's default executor. A call blocked inside the C library (a dead link, a transfer the
autopilot never finishes) keeps its worker thread: Python 3.11's ``asyncio.run`` then joins that
thread without a bound, and so does the interpreter at exit. After a failure the companion must
exit and say why, so both waits are bounded here.
"""

from __future__ import annotations

import asyncio
import logging
import os
import sys
import threading
from collections.abc import Coroutine
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")

WORKER_PREFIX = "companion-worker"
THREAD_GRACE_S = 5.0  # wall: what a worker thread still running at the end gets to finish


def run_bounded(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(main)``: every task left is cancelled and awaited, async generators closed;
    the default executor is shut down without waiting for its threads (see :func:`leave`)."""
    executor = ThreadPoolExecutor(thread_name_prefix=WORKER_PREFIX)
    loop = asyncio.new_event_loop()
    loop.set_default_executor(executor)
    asyncio.set_event_loop(loop)
    try:
        return loop.run_until_complete(main)
    finally:
        try:
            _cancel_all(loop)
            loop.run_until_complete(loop.shutdown_asyncgens())
        finally:
            asyncio.set_event_loop(None)
            executor.shutdown(wait=False, cancel_futures=True)
            loop.close()


def _cancel_all(loop: asyncio.AbstractEventLoop) -> None:
    tasks = [t for t in asyncio.all_tasks(loop) if not t.done()]
    for t in tasks:
        t.cancel()
    if tasks:
        loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))


def blocked_threads(grace_s: float = THREAD_GRACE_S) -> list[str]:
    """Names of the non-daemon threads still alive after waiting up to ``grace_s`` for them all."""
    deadline = threading.Event()
    timer = threading.Timer(grace_s, deadline.set)
    timer.daemon = True
    timer.start()
    try:
        for t in threading.enumerate():
            if t is threading.current_thread() or t.daemon or t is timer:
                continue
            while t.is_alive() and not deadline.is_set():
                t.join(0.05)
    finally:
        timer.cancel()
    return [t.name for t in threading.enumerate()
            if t is not threading.current_thread() and not t.daemon and t.is_alive() and t is not timer]


def leave(code: int, grace_s: float = THREAD_GRACE_S) -> int:
    """Return ``code`` when every worker thread has ended within ``grace_s``; otherwise name them
    on stderr, flush, and end the process at once with ``code`` (the interpreter would join them
    for ever)."""
    stuck = blocked_threads(grace_s)
    if not stuck:
        return code
    line = (f"{len(stuck)} worker thread(s) still blocked after {grace_s:g} s ({', '.join(stuck)}), "
            "most likely in a MAVSDK call to a vehicle that stopped answering: exiting without them")
    print(f"companion: {line}", file=sys.stderr)
    logging.getLogger("companion").warning("%s", line)
    sys.stdout.flush()
    sys.stderr.flush()
    logging.shutdown()
    os._exit(code)
