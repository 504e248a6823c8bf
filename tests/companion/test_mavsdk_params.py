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


def test_a_parameter_is_read_by_name_as_float_else_int_without_the_list():
    fake = ScriptedParams()
    params = MavsdkParams(fake, "a")

    async def scenario():
        return await params.get("COM_OF_LOSS_T"), await params.get("COM_OBL_RC_ACT"), await params.get("COM_OF_LOSS_T")
    assert asyncio.run(scenario()) == (4.0, 5.0, 4.0)
    assert fake.list_calls == 0  # PX4's ~900-message list is never asked for
    assert fake.reads == [("COM_OF_LOSS_T", "float"), ("COM_OBL_RC_ACT", "float"), ("COM_OBL_RC_ACT", "int")]
    assert params.known("COM_OF_LOSS_T") == 4.0


def test_a_read_without_an_answer_asks_the_list_whether_the_name_exists():
    fake = ScriptedParams(lists=["ok"], singles=[ParamResult.TIMEOUT])
    params = MavsdkParams(fake, "a")

    async def scenario():
        return await params.get("MIS_TAKEOFF_ALT"), await params.get("COM_OF_LOSS_T")
    assert asyncio.run(scenario()) == (None, 4.0)  # absent (not PX4), and the other from the list
    assert fake.list_calls == 1 and fake.reads == [("MIS_TAKEOFF_ALT", "float")]


def test_a_lost_answer_is_read_again_when_the_list_is_lost_too():
    fake = ScriptedParams(lists=[ParamResult.TIMEOUT] * 2, singles=[ParamResult.TIMEOUT])
    params = MavsdkParams(fake, "b")
    assert asyncio.run(params.get("COM_OF_LOSS_T")) == 4.0
    assert fake.list_calls == 2 and fake.reads == [("COM_OF_LOSS_T", "float")] * 2


def test_a_parameter_that_cannot_be_read_at_all_is_named_with_the_tries():
    fake = ScriptedParams(lists=[ParamResult.TIMEOUT] * 2, singles=[ParamResult.TIMEOUT] * 3)
    with pytest.raises(CommandRefused) as err:
        asyncio.run(MavsdkParams(fake, "b").get("COM_DISARM_PRFLT"))
    text = str(err.value)
    assert text.startswith("vehicle 'b': read COM_DISARM_PRFLT refused: TIMEOUT (by name: 3 attempt(s) in "), text
    assert "; the list: 2 attempt(s) in " in text and text.endswith(" s wall)"), text
    assert fake.list_calls == 2  # the list is asked for once (two tries), not for every try by name


def test_a_list_that_never_answers_ends_at_its_bound():
    fake = ScriptedParams(lists=["hang"], singles=[ParamResult.TIMEOUT] * 3)
    with pytest.raises(CommandRefused, match=r"read MIS_TAKEOFF_ALT refused: TIMEOUT .*the list: 1 attempt"):
        asyncio.run(MavsdkParams(fake, "a", list_timeout_s=0.2).get("MIS_TAKEOFF_ALT"))


def test_a_refusal_that_will_not_change_is_not_tried_again():
    fake = ScriptedParams(singles=[ParamResult.NO_SYSTEM])
    with pytest.raises(CommandRefused, match="NO_SYSTEM"):
        asyncio.run(MavsdkParams(fake, "a").get("COM_OF_LOSS_T"))
    assert fake.list_calls == 0 and len(fake.reads) == 1


def test_a_set_is_sent_as_the_type_read_and_retried_on_a_timeout():
    fake = ScriptedParams(sets=[ParamResult.TIMEOUT, None])
    params = MavsdkParams(fake, "a")

    async def scenario():
        await params.get("COM_OBL_RC_ACT")
        await params.set("COM_OBL_RC_ACT", 5.0)
        return await params.get("COM_OBL_RC_ACT")
    assert asyncio.run(scenario()) == 5.0
    assert fake.set_calls == [("COM_OBL_RC_ACT", 5), ("COM_OBL_RC_ACT", 5)]  # INT32, as read
    assert fake.reads == [("COM_OBL_RC_ACT", "float"), ("COM_OBL_RC_ACT", "int")]  # the set value is kept


def test_a_set_that_keeps_timing_out_names_the_parameter():
    fake = ScriptedParams(sets=[ParamResult.TIMEOUT] * 3)
    with pytest.raises(CommandRefused, match=r"set MIS_TAKEOFF_ALT refused: TIMEOUT \(3 attempt\(s\)\)"):
        asyncio.run(MavsdkParams(fake, "a").set("MIS_TAKEOFF_ALT", 20.0))
