"""The line: conveyors, side guides and photo-eyes, as the ``[line]`` table describes them.

One schema serves scenario files and measured datasets (contracts/measured-data.md), so a
line measured on a plant floor and a line simulated here are described the same way.

Frame: x along the flow (0 at the upstream end of the first conveyor), y across (positive to
the left looking downstream, 0 on the centre line), z up (0 at the top of the first conveyor).

>>> line = Line.model_validate({"guide_width_m": 0.5,
...     "conveyors": [{"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0}],
...     "photoeyes": [{"id": "pe", "x_m": 1.9, "z_m": 0.015}]})
>>> line.conveyor_at(1.0).id, line.x_end_m
('c1', 2.0)
"""

from __future__ import annotations

from typing import Annotated

import pydantic
from pydantic import Field

from plant.validation import Strict, ValueAtKey

Id = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z_][A-Za-z0-9_\-]*$")]


class Conveyor(Strict):
    """A straight belt along x; its top surface moves at the speed its drive delivers."""

    id: Id = Field(description=(
        "unique among conveyors and photo-eyes; names the belt's plant ports (plant.<id>.speed, "
        ".load_force, .load_mass)"))
    x_start_m: float = Field(ge=-100.0, le=1000.0, description=(
        "upstream end of the belt's top surface; at or after the end of the conveyor before, gaps up to 0.5 m"))
    length_m: float = Field(gt=0.05, le=200.0, description="length of the flat top surface along x")
    width_m: float = Field(gt=0.05, le=5.0, description="belt width across y; at least guide_width_m")
    z_top_m: float = Field(ge=-10.0, le=10.0, description=(
        "height of the top surface; a conveyor may step down from the one before, by at most 0.5 m, not up"))

    @property
    def x_end_m(self) -> float:
        return self.x_start_m + self.length_m


class PhotoEye(Strict):
    """A light beam across the line (along y) at x, height z: blocked when a fish is in it."""

    id: Id = Field(description="unique among conveyors and photo-eyes; its plant port is plant.<id>.blocked")
    x_m: float = Field(ge=-100.0, le=1000.0, description="position of the beam along the line, between its ends")
    z_m: float = Field(ge=-10.0, le=10.0, description=(
        "beam height (absolute z): above the belt top there, by at most 0.5 m"))


class Line(Strict):
    """Conveyors in flow order, side guides along the whole line, photo-eyes."""

    guide_width_m: float = Field(gt=0.05, le=5.0, description="side guides at y = +-guide_width_m/2")
    conveyors: list[Conveyor] = Field(min_length=1, max_length=64, description="the belts, in flow order")
    photoeyes: list[PhotoEye] = Field(default_factory=list, max_length=256, description="light beams across the line")

    @pydantic.model_validator(mode="after")
    def _check_geometry(self) -> "Line":
        ids = [c.id for c in self.conveyors] + [p.id for p in self.photoeyes]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueAtKey("conveyors", f"ids must be unique across conveyors and photo-eyes; repeated: {', '.join(dup)}")
        for i, (a, b) in enumerate(zip(self.conveyors, self.conveyors[1:])):
            if b.x_start_m < a.x_end_m - 1e-9:
                raise ValueAtKey(f"conveyors.{i + 1}.x_start_m",
                    f"conveyors[{i + 1}] ('{b.id}') starts at x = {b.x_start_m} m, inside conveyors[{i}] "
                    f"('{a.id}') which ends at x = {a.x_end_m:g} m: conveyors overlap or are not in flow order")
            if b.x_start_m - a.x_end_m > 0.5:
                raise ValueAtKey(f"conveyors.{i + 1}.x_start_m",
                    f"gap of {b.x_start_m - a.x_end_m:.3f} m between '{a.id}' and '{b.id}': fish would fall "
                    "through; gaps up to 0.5 m are supported")
            if b.z_top_m > a.z_top_m + 1e-3:
                raise ValueAtKey(f"conveyors.{i + 1}.z_top_m",
                    f"conveyors[{i + 1}] ('{b.id}') top z_top_m = {b.z_top_m} is above '{a.id}' "
                    f"({a.z_top_m}): a step up stops fish; only steps down are supported")
            if a.z_top_m - b.z_top_m > 0.5:
                raise ValueAtKey(f"conveyors.{i + 1}.z_top_m", f"step down of {a.z_top_m - b.z_top_m:.3f} m from '{a.id}' to '{b.id}' "
                                 "is more than 0.5 m: that is a drop, not a transfer")
        for i, c in enumerate(self.conveyors):
            if c.width_m < self.guide_width_m - 1e-9:
                raise ValueAtKey(f"conveyors.{i}.width_m",
                    f"conveyors[{i}] ('{c.id}') width_m = {c.width_m} is narrower than guide_width_m = "
                    f"{self.guide_width_m}: fish would fall between belt edge and guide")
        for i, p in enumerate(self.photoeyes):
            if not (self.x_start_m <= p.x_m <= self.x_end_m):
                raise ValueAtKey(f"photoeyes.{i}.x_m", f"photoeyes[{i}] ('{p.id}') at x_m = {p.x_m} is outside the line "
                                 f"[{self.x_start_m:g}, {self.x_end_m:g}] m")
            top = self.z_top_at(p.x_m)
            if not (top < p.z_m <= top + 0.5):
                raise ValueAtKey(f"photoeyes.{i}.z_m", f"photoeyes[{i}] ('{p.id}') beam z_m = {p.z_m} must be above the belt top "
                                 f"there (z = {top:g} m) and at most 0.5 m above it")
        return self

    @property
    def x_start_m(self) -> float:
        return self.conveyors[0].x_start_m

    @property
    def x_end_m(self) -> float:
        return self.conveyors[-1].x_end_m

    def conveyor_at(self, x_m: float) -> Conveyor:
        """The conveyor under x (in a gap: the downstream one; outside the line: the nearest end)."""
        for c in self.conveyors:
            if x_m < c.x_end_m:
                return c
        return self.conveyors[-1]

    def z_top_at(self, x_m: float) -> float:
        return self.conveyor_at(x_m).z_top_m

    def conveyor(self, conveyor_id: str) -> Conveyor:
        for c in self.conveyors:
            if c.id == conveyor_id:
                return c
        raise KeyError(conveyor_id)

    def photoeye(self, photoeye_id: str) -> PhotoEye:
        for p in self.photoeyes:
            if p.id == photoeye_id:
                return p
        raise KeyError(photoeye_id)


class KpiSettings(Strict):
    """The ``[kpi]`` table (contracts/kpis.md): which beams count fish in and out, and the gap needed."""

    infeed_photoeye: Id | None = Field(None, description="the beam at the infeed, if any; a photo-eye of the line")
    outfeed_photoeye: Id = Field(description=(
        "the beam at which fish are counted out and singulation is judged; a photo-eye of the line"))
    min_gap_m: float = Field(default=0.05, ge=0.0, le=5.0, description=(
        "least gap along x, at belt speed, to the fish before and after for a fish to count as singulated "
        "(contracts/kpis.md); the beam's clear moments shorter than this are flicker, not a gap"))

    def check_against(self, line: Line) -> None:
        """Raise ValueError if a named photo-eye is not on the line."""
        names = [p.id for p in line.photoeyes]
        for key in ("outfeed_photoeye", "infeed_photoeye"):
            value = getattr(self, key)
            if value is not None and value not in names:
                raise ValueAtKey(f"kpi.{key}", f"'{value}' is not a photo-eye of the line (photo-eyes: {', '.join(names) or 'none'})")
