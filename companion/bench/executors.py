"""Where the bench's scenarios run: one ``concurrent.futures.Executor``, local or on Dask.

    ExecutorSpec(ExecutorKind.LOCAL, workers=2)                    a process pool (1: this process)
    ExecutorSpec(ExecutorKind.DASK, workers=4)                     a distributed.LocalCluster on loopback
    ExecutorSpec(ExecutorKind.DASK, scheduler="tcp://host:8786")   an existing Dask cluster

    with open_pool(spec) as pool:       # pool.executor, pool.window, pool.where
        ...

Every path yields a plain ``Executor`` (Dask's through ``Client.get_executor()``), so the bench
submits and collects with one piece of code whatever runs the work.
"""

from __future__ import annotations

import contextlib
import enum
import gc
import os
import re
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from companion.cli.errors import BadInput

CONNECT_TIMEOUT_S = 10.0  # to reach a scheduler, and then to see its first worker
_ADDRESS = re.compile(r"^(tcp|tls)://[^\s/:]+:\d{1,5}$")


class ExecutorKind(enum.Enum):
    LOCAL = "local"
    DASK = "dask"


class ExecutorError(BadInput):
    """The executor cannot be set up or lost its workers; ``str()`` is one line for the user (exit 2)."""


@dataclass(frozen=True)
class ExecutorSpec:
    """What to run on; validated on construction (:class:`ExecutorError`)."""

    kind: ExecutorKind = ExecutorKind.LOCAL
    workers: int | None = None  # local processes / LocalCluster workers; None: os.cpu_count()
    scheduler: str | None = None  # dask only: an existing scheduler's address
    connect_timeout_s: float = CONNECT_TIMEOUT_S

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise ExecutorError(f"--workers must be at least 1 (got {self.workers})")
        if self.scheduler is None:
            return
        if self.kind is not ExecutorKind.DASK:
            raise ExecutorError("--scheduler needs --executor dask")
        if self.workers is not None:
            raise ExecutorError("--workers sizes a local cluster; with --scheduler the cluster's workers are used")
        if not _ADDRESS.match(self.scheduler):
            raise ExecutorError(f"--scheduler: not a scheduler address {self.scheduler!r} (e.g. tcp://10.0.0.5:8786)")

    def describe(self) -> str:
        """The command-line options that select this executor."""
        if self.kind is ExecutorKind.LOCAL:
            return f"--workers {self.workers or os.cpu_count() or 1}"
        where = f"--scheduler {self.scheduler}" if self.scheduler else f"--workers {self.workers or os.cpu_count() or 1}"
        return f"--executor dask {where}"


@dataclass(frozen=True)
class Pool:
    executor: Executor
    window: int  # tasks kept submitted at once: enough to keep every worker busy
    where: str  # for the user: "2 local processes", "dask tcp://... (8 threads)"


class InlineExecutor(Executor):
    """Runs each task in this process when it is submitted (tests, profiling, ``--workers 1``)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered through the future, as a pool would
            future.set_exception(exc)
        return future


@contextlib.contextmanager
def open_pool(spec: ExecutorSpec) -> Iterator[Pool]:
    """The executor ``spec`` names, shut down (cluster and all) on exit."""
    if spec.kind is ExecutorKind.DASK:
        with _dask_pool(spec) as pool:
            yield pool
        return
    workers = spec.workers or os.cpu_count() or 1
    if workers == 1:
        with fewer_gc_passes():
            yield Pool(InlineExecutor(), 1, "this process")
        return
    with ProcessPoolExecutor(max_workers=workers, initializer=worker_init) as executor:
        yield Pool(executor, 2 * workers, f"{workers} local processes")


@contextlib.contextmanager
def _dask_pool(spec: ExecutorSpec) -> Iterator[Pool]:
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ExecutorError("--executor dask needs Dask: pip install 'astar-bdwa[dask]'") from None
    with contextlib.ExitStack() as stack:
        try:
            if spec.scheduler is not None:
                client = stack.enter_context(Client(spec.scheduler, timeout=spec.connect_timeout_s,
                                                    set_as_default=False))
                where = f"dask {spec.scheduler}"
            else:
                # Loopback only: a local cluster is nobody else's business.
                cluster = stack.enter_context(LocalCluster(
                    n_workers=spec.workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                    host="127.0.0.1", dashboard_address=None))
                client = stack.enter_context(Client(cluster, timeout=spec.connect_timeout_s, set_as_default=False))
                client.run(worker_init)  # our own worker processes: fewer collector passes for good
                where = f"dask LocalCluster {cluster.scheduler_address}"
        except (OSError, TimeoutError, RuntimeError) as exc:
            target = spec.scheduler or "a local Dask cluster"
            raise ExecutorError(f"cannot use {target}: {_first_line(exc)}") from None
        try:
            client.wait_for_workers(1, timeout=spec.connect_timeout_s)
        except (OSError, TimeoutError) as exc:
            raise ExecutorError(f"no worker joined {spec.scheduler or 'the local Dask cluster'} within "
                                f"{spec.connect_timeout_s:g} s (start one with `dask worker {spec.scheduler or 'ADDRESS'} "
                                f"--nthreads 1`): {_first_line(exc)}") from None
        slots = sum(client.nthreads().values())
        yield Pool(client.get_executor(), 2 * max(slots, 1), f"{where} ({slots} worker threads)")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


_GEN0 = 20_000


def _fewer_gc_passes(gen0: int) -> tuple[int, int, int]:
    """A run allocates a few small objects per vehicle-tick (results, commands, snapshots) that
    die young and form no cycles, so the default young-generation threshold (700) makes the
    collector scan over and over for nothing: 5-10 % of the bench's CPU. The long-lived objects
    so far are frozen out of the scans and the threshold is raised; returns the old thresholds."""
    saved = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(gen0, saved[1], saved[2])
    return saved


@contextlib.contextmanager
def fewer_gc_passes(gen0: int = _GEN0):
    """:func:`_fewer_gc_passes` until exit."""
    saved = _fewer_gc_passes(gen0)
    try:
        yield
    finally:
        gc.set_threshold(*saved)
        gc.unfreeze()


def worker_init() -> None:
    """A worker process lives for the bench only: fewer collector passes for good. (Not by
    entering :func:`fewer_gc_passes` and dropping it: the dropped generator is closed at once,
    which ran its ``finally`` and undid the settings before the first task.)"""
    _fewer_gc_passes(_GEN0)
