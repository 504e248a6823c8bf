"""The BDWA score weights (w_h, w_d, w_s) as one value: applied to a mission, written to a
replayable scenario document, stored in runs.csv columns, and crossed into a sweep grid."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from uav_model.mission import Mission, mission_schema

COLUMNS = ("w_heading", "w_distance", "w_sightline")


@dataclass(frozen=True, order=True)
class Weights:
    heading: float
    distance: float
    sightline: float

    @classmethod
    def default(cls) -> "Weights":
        """The mission schema's defaults: the paper's 0.37 / 0.6 / 0.8."""
        props = mission_schema()["$defs"]["planner"]["properties"]["weights"]["properties"]
        return cls(*(float(props[k]["default"]) for k in ("heading", "distance", "sightline")))

    def apply(self, mission: Mission) -> Mission:
        """The same mission flown with these weights."""
        return dataclasses.replace(mission, planner=dataclasses.replace(
            mission.planner, weight_heading=self.heading, weight_distance=self.distance,
            weight_sightline=self.sightline))

    def apply_doc(self, doc: Mapping[str, Any]) -> dict[str, Any]:
        """A mission document that loads to ``apply(mission)`` (what a failure replays from)."""
        weights = {"heading": self.heading, "distance": self.distance, "sightline": self.sightline}
        return {**doc, "planner": {**doc.get("planner", {}), "weights": weights}}

    @property
    def label(self) -> str:
        return f"{self.heading:g}/{self.distance:g}/{self.sightline:g}"

    @property
    def tag(self) -> str:
        """For file names: ``w0.37-0.6-0.8``."""
        return f"w{self.heading:g}-{self.distance:g}-{self.sightline:g}"

    def columns(self) -> dict[str, float]:
        return dict(zip(COLUMNS, (self.heading, self.distance, self.sightline)))

    @classmethod
    def from_row(cls, row: Mapping[str, Any]) -> "Weights | None":
        """The weights a runs.csv row was flown with; None for a plain bench row."""
        if row.get(COLUMNS[0]) is None:
            return None
        return cls(*(float(row[c]) for c in COLUMNS))


def grid(headings: Sequence[float], distances: Sequence[float], sightlines: Sequence[float]) -> tuple[Weights, ...]:
    """Every combination, heading slowest (the order runs.csv and the table use)."""
    return tuple(Weights(h, d, s) for h, d, s in itertools.product(headings, distances, sightlines))
