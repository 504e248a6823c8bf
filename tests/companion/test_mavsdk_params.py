"""Parameter reads and writes over MAVSDK's param plugin: retried within a bound, named when they fail.

MAVSDK's own ParamAsync needs a live autopilot that can be made to time out on demand; this
stands in for it with the same calls and the same errors (mavsdk.plugins.param's ParamError,
AllParams, IntParam, FloatParam)."""

from __future__ import annotations

import asyncio

import pytest
from mavsdk.plugins.param import AllParams, FloatParam, IntParam, ParamError, ParamResult

from companion.errors import CommandRefused
from companion.vehicle.mavsdk_params import MavsdkParams


class ScriptedParams:
    """MAVSDK's ParamAsync calls, answering from a script of results (a result: that ParamError)."""

    def __init__(self, *, lists=(), sets=(), singles=()):
        self.lists = list(lists)
        self.singles = list(singles)
        self.reads: list[tuple[str, str]] = []
        self.sets = list(sets)
        self.list_calls = 0
        self.set_calls: list[tuple[str, object]] = []

    async def get_all_params(self):
        self.list_calls += 1
        answer = self.lists.pop(0)
        if isinstance(answer, ParamResult):
            raise ParamError(answer, "get_all_params")
        if answer == "hang":
            await asyncio.sleep(3600)
        return AllParams([IntParam("COM_OBL_RC_ACT", 0)], [FloatParam("COM_OF_LOSS_T", 4.0)])

    async def get_param_float(self, name):
        return await self._get(name, float)

    async def get_param_int(self, name):
        return await self._get(name, int)

    async def _get(self, name, kind):
        self.reads.append((name, kind.__name__))
        answer = self.singles.pop(0) if self.singles else None
        if answer is not None:
            raise ParamError(answer, "get_param")
        if (name == "COM_OBL_RC_ACT") != (kind is int):
            raise ParamError(ParamResult.WRONG_TYPE, "get_param")
        return kind(5 if kind is int else 4.0)

    async def _set(self, name, value):
        self.set_calls.append((name, value))
        answer = self.sets.pop(0) if self.sets else None
        if answer is not None:
            raise ParamError(answer, "set_param")

    async def set_param_int(self, name, value):
        await self._set(name, value)

    async def set_param_float(self, name, value):
        await self._set(name, value)


def test_a_list_that_times_out_is_read_again():
    fake = ScriptedParams(lists=[ParamResult.TIMEOUT, "ok"])
    params = MavsdkParams(fake, "a")
    assert asyncio.run(params.get("COM_OF_LOSS_T")) == 4.0
    assert fake.list_calls == 2 and not fake.reads


def test_a_list_that_keeps_timing_out_is_read_by_name_instead():
    fake = ScriptedParams(lists=[ParamResult.TIMEOUT] * 2, singles=[ParamResult.TIMEOUT])
    params = MavsdkParams(fake, "b")

    async def scenario():
        return await params.get("COM_OF_LOSS_T"), await params.get("COM_OBL_RC_ACT"), params.known("COM_OF_LOSS_T")
    assert asyncio.run(scenario()) == (4.0, 5.0, 4.0)
    assert fake.list_calls == 2  # the list is not asked for again
    assert fake.reads == [("COM_OF_LOSS_T", "float"), ("COM_OF_LOSS_T", "float"),
                          ("COM_OBL_RC_ACT", "float"), ("COM_OBL_RC_ACT", "int")]


def test_a_parameter_that_cannot_be_read_at_all_is_named_with_the_tries():
    fake = ScriptedParams(lists=[ParamResult.TIMEOUT] * 2, singles=[ParamResult.TIMEOUT] * 3)
    with pytest.raises(CommandRefused) as err:
        asyncio.run(MavsdkParams(fake, "b").get("COM_DISARM_PRFLT"))
    assert str(err.value).startswith("vehicle 'b': read COM_DISARM_PRFLT refused: TIMEOUT (the list: "
                                     "2 attempt(s) in ")
    assert str(err.value).endswith("; by name: 3 attempt(s))")


def test_a_list_that_never_answers_ends_at_the_bound():
    fake = ScriptedParams(lists=["hang"], singles=[ParamResult.NO_SYSTEM])
    with pytest.raises(CommandRefused, match=r"read MIS_TAKEOFF_ALT refused: NO_SYSTEM \(the list: 1 attempt"):
        asyncio.run(MavsdkParams(fake, "a", list_timeout_s=0.2).get("MIS_TAKEOFF_ALT"))


def test_a_refusal_that_will_not_change_is_not_tried_again():
    fake = ScriptedParams(lists=[ParamResult.NO_SYSTEM], singles=[ParamResult.NO_SYSTEM])
    with pytest.raises(CommandRefused, match="NO_SYSTEM"):
        asyncio.run(MavsdkParams(fake, "a").get("COM_OF_LOSS_T"))
    assert fake.list_calls == 1 and len(fake.reads) == 1


def test_a_set_is_sent_as_the_type_read_and_retried_on_a_timeout():
    fake = ScriptedParams(lists=["ok"], sets=[ParamResult.TIMEOUT, None])
    params = MavsdkParams(fake, "a")

    async def scenario():
        await params.get("COM_OBL_RC_ACT")
        await params.set("COM_OBL_RC_ACT", 5.0)
        return await params.get("COM_OBL_RC_ACT")
    assert asyncio.run(scenario()) == 5.0
    assert fake.set_calls == [("COM_OBL_RC_ACT", 5), ("COM_OBL_RC_ACT", 5)]  # INT32, as read


def test_a_set_that_keeps_timing_out_names_the_parameter():
    fake = ScriptedParams(lists=["ok"], sets=[ParamResult.TIMEOUT] * 3)
    with pytest.raises(CommandRefused, match=r"set MIS_TAKEOFF_ALT refused: TIMEOUT \(3 attempt\(s\)\)"):
        asyncio.run(MavsdkParams(fake, "a").set("MIS_TAKEOFF_ALT", 20.0))
