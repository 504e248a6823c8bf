"""An autopilot's parameters over MAVSDK's param plugin: read once as a list, retried within a bound.

    params = MavsdkParams(ParamAsync(system), "a")
    await params.get("COM_OF_LOSS_T")   -> 1.0 (None: the autopilot has no such parameter)
    await params.set("MIS_TAKEOFF_ALT", 20.0)

PX4 ignores a request for a name it does not have, and MAVSDK then retries it for 3 s, queueing
every later request behind it: so the whole list is read once (PARAM_REQUEST_LIST) and kept up to
date by :meth:`MavsdkParams.set`. On a flooded link or a loaded machine one list transfer can
time out (PX4 sends ~900 parameters in a burst, and a loaded machine misses most of them); it is
tried again within one wall-clock bound, and then each parameter is read by name (one message
each way, retried). A final failure names the parameter, the tries and the time.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable

from mavsdk.plugins.param import ParamError, ParamResult

from companion.errors import CommandRefused

PARAM_LIST_TIMEOUT_S = 45.0  # wall, for every try together; PX4 SITL sends its list in about a second
PARAM_LIST_ATTEMPTS = 2
PARAM_READ_ATTEMPTS = 3  # by name, once the list has failed
PARAM_SET_ATTEMPTS = 3  # MAVSDK resends a PARAM_SET 5 times itself; a try is that whole cycle
SET_TIMEOUT_S = 10.0  # wall, one try (MAVSDK gives up after ~3 s itself)
log = logging.getLogger(__name__)
_RETRYABLE = frozenset({ParamResult.TIMEOUT, ParamResult.CONNECTION_ERROR, ParamResult.UNKNOWN})
_WRONG_TYPE = frozenset({ParamResult.WRONG_TYPE, ParamResult.TYPE_MISMATCH})


class MavsdkParams:
    """The parameters of one autopilot (``param``: MAVSDK's ``ParamAsync``)."""

    def __init__(self, param, vehicle: str, *, list_timeout_s: float = PARAM_LIST_TIMEOUT_S,
                 list_attempts: int = PARAM_LIST_ATTEMPTS):
        self._param = param
        self._vehicle = vehicle
        self._list_timeout_s = list_timeout_s
        self._list_attempts = list_attempts
        self._values: dict[str, float] | None = None  # all of the autopilot's, read once
        self._ints: set[str] = set()  # which of them are INT32
        self._list_failure: str | None = None  # why the list could not be read (then: by name)
        self._lock = asyncio.Lock()

    def known(self, name: str) -> float | None:
        """The value read before, without asking the autopilot (None: not read, or no such name)."""
        return None if self._values is None else self._values.get(name)

    async def get(self, name: str) -> float | None:
        async with self._lock:
            if self._values is None:
                try:
                    await self._read_all(name)
                except CommandRefused as exc:  # a flooded link loses the list's burst: ask by name
                    self._values, self._list_failure = {}, exc.detail
                    log.warning("%s; reading parameters one by one", exc)
            assert self._values is not None
            if name not in self._values and self._list_failure is not None:
                self._values[name] = await self._read_one(name)
        return self._values.get(name)

    async def _read_all(self, wanted: str) -> None:
        started = time.monotonic()
        deadline = started + self._list_timeout_s
        last, tries = "TIMEOUT", 0
        while tries < self._list_attempts and (left := deadline - time.monotonic()) > 0:
            tries += 1
            try:
                # MAVSDK times a transfer out itself (then another try); the bound is the backstop:
                # a call abandoned early would leave its worker thread blocked in the C library.
                async with asyncio.timeout(left):
                    everything = await self._param.get_all_params()
            except TimeoutError:
                last = "TIMEOUT"
                continue
            except ParamError as exc:
                last = exc.result.name
                if exc.result not in _RETRYABLE:
                    break
                continue
            self._values = {p.name: float(p.value) for p in (*everything.int_params, *everything.float_params)}
            self._ints = {p.name for p in everything.int_params}
            return
        raise CommandRefused(f"read parameters (for {wanted})", last, vehicle=self._vehicle, detail=(
            f"{tries} attempt(s) in {time.monotonic() - started:.1f} s wall"))

    async def _read_one(self, name: str) -> float:
        """One parameter by name (PARAM_REQUEST_READ), as a float, else as an INT32."""
        result = ParamResult.TIMEOUT
        for attempt in range(1, PARAM_READ_ATTEMPTS + 1):
            try:
                async with asyncio.timeout(SET_TIMEOUT_S):
                    try:
                        return float(await self._param.get_param_float(name))
                    except ParamError as exc:
                        if exc.result not in _WRONG_TYPE:
                            raise
                    value = float(await self._param.get_param_int(name))
                    self._ints.add(name)
                    return value
            except TimeoutError:
                result = ParamResult.TIMEOUT
            except ParamError as exc:
                result = exc.result
                if result not in _RETRYABLE:
                    break
        raise CommandRefused(f"read {name}", result.name, vehicle=self._vehicle,
                             detail=f"the list: {self._list_failure}; by name: {attempt} attempt(s)")

    async def set(self, name: str, value: float) -> None:
        """Set one parameter as the type it was read with (an INT32 sent as a float: PX4 rejects
        it), tried again while the answer is a timeout."""
        kinds: tuple[type, type] = (int, float) if name in self._ints else (float, int)
        for attempt in range(1, PARAM_SET_ATTEMPTS + 1):
            try:
                async with asyncio.timeout(SET_TIMEOUT_S):
                    await self._set_either(name, value, kinds)
                break
            except TimeoutError:
                result = ParamResult.TIMEOUT
            except ParamError as exc:
                result = exc.result
            if result not in _RETRYABLE or attempt == PARAM_SET_ATTEMPTS:
                raise CommandRefused(f"set {name}", result.name, vehicle=self._vehicle,
                                     retryable=result in _RETRYABLE, detail=f"{attempt} attempt(s)")
        if self._values is not None:
            self._values[name] = float(value)

    async def _set_either(self, name: str, value: float, kinds: tuple[type, type]) -> None:
        try:
            await self._setter(kinds[0])(name, value)
        except ParamError as exc:
            if exc.result not in _WRONG_TYPE:
                raise
            await self._setter(kinds[1])(name, value)

    def _setter(self, kind: type) -> Callable[[str, float], Awaitable[None]]:
        p = self._param
        if kind is int:
            return lambda n, v: p.set_param_int(n, int(round(v)))
        return lambda n, v: p.set_param_float(n, float(v))
