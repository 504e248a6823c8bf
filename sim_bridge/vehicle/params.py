"""The vehicle's parameters and the MAVLink parameter protocol (PARAM_SET / _REQUEST_READ / _LIST)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Hashable

from pymavlink.dialects.v20 import common as mavlink

from uav_model.plant import Plant, PlantLimits, limits_for
from sim_bridge.vehicle.px4 import ParamDef, ParamType
from sim_bridge.vehicle.types import Emit, float_bits_to_int32, int32_to_float_bits

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle


class ParamStore:
    """PX4-named parameters with their defaults, bounds and wire types."""

    def __init__(self, v: "SimVehicle", defs: tuple[ParamDef, ...], max_alt_m: float, plant: Plant):
        self._v = v
        self._plant = plant
        self.defs: dict[str, ParamDef] = {d.name: d for d in defs}
        self.order: tuple[str, ...] = tuple(d.name for d in defs)
        self.values: dict[str, float] = {d.name: float(d.default) for d in defs}
        self.max_alt_m = max_alt_m
        self.limits = self._limits()

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def override(self, name: str, value: float) -> None:
        """Set a parameter before flight (as a SITL startup script does); ValueError if it cannot be."""
        d = self.defs.get(name)
        if d is None:
            raise ValueError(f"unknown parameter {name!r}")
        if not d.accepts(float(value)):
            raise ValueError(f"parameter {name}: {value!r} is outside [{d.min_value:g}, {d.max_value:g}]")
        self.values[name] = float(value)
        self.limits = self._limits()

    def _limits(self) -> PlantLimits:
        p = self.values
        return limits_for(self._plant, speed_m_s=p["MPC_XY_VEL_MAX"], max_yaw_rate_rad_s=math.radians(p["MPC_YAWRAUTO_MAX"]),
                          max_accel_m_s2=p["MPC_ACC_HOR"], max_climb_m_s=max(p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"]),
                          max_alt_m=self.max_alt_m, params=p)

    def value_msg(self, name: str) -> Any:
        d = self.defs[name]
        value = self.values[name]
        wire = int32_to_float_bits(int(value)) if d.type is ParamType.INT32 else value  # PX4 is bytewise
        return self._v.mav.param_value_encode(name.encode("ascii"), wire, int(d.type), len(self.order),
                                              self.order.index(name))

    def on_param_set(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        v = self._v
        name = str(msg.param_id).rstrip("\x00")
        d = self.defs.get(name)
        if d is None:
            v.counters["param_unknown"] += 1
            return []
        raw = float(msg.param_value)
        value = float(float_bits_to_int32(raw)) if d.type is ParamType.INT32 else raw
        if not d.accepts(value):
            v.counters["param_rejected"] += 1
            return [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_WARNING, f"param {name}: {value!r} rejected"), link, peer),
                    Emit(self.value_msg(name), link, peer)]
        self.values[name] = value
        self.limits = self._limits()
        if name == "MPC_XY_CRUISE":
            v.nav.mission_speed_m_s = value
        return [Emit(self.value_msg(name))]  # PX4 broadcasts a changed value

    def on_param_request_read(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        idx = int(msg.param_index)
        if idx >= 0:
            if idx >= len(self.order):
                self._v.counters["param_unknown"] += 1
                return []
            name = self.order[idx]
        else:
            name = str(msg.param_id).rstrip("\x00")
            if name not in self.defs:
                self._v.counters["param_unknown"] += 1
                return []
        return [Emit(self.value_msg(name), link, peer)]

    def on_param_request_list(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        return [Emit(self.value_msg(n), link, peer) for n in self.order]
