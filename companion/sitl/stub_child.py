"""Entry point of the embedded stub's child process: ``sim-bridge`` that dies with its parent.

The companion keeps the child's stdin open and never writes to it. When the companion exits in
any way, including SIGKILL, the OS closes that pipe; the watcher thread sees end-of-file and
sends the stub SIGTERM, which stops it cleanly. No orphan keeps flying after the companion.
"""

from __future__ import annotations

import os
import signal
import sys
import threading


def _watch_parent() -> None:
    # Raw reads of fd 0 until EOF (the parent is gone, or closed the pipe to stop us). Not
    # sys.stdin.buffer: a daemon thread blocked in it holds the reader's lock, and the interpreter's
    # shutdown then aborted with "Fatal Python error: could not acquire lock for <stdin>".
    while os.read(0, 4096):
        pass
    os.kill(os.getpid(), signal.SIGTERM)


def main() -> int:
    from sim_bridge.cli import main as sim_main
    threading.Thread(target=_watch_parent, name="parent-watch", daemon=True).start()
    return sim_main(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
