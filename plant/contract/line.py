"""The line: conveyors, side guides, photo-eyes and cameras, as the ``[line]`` table describes them.

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


class Camera(Strict):
    """A vision system looking down on the line: its field of view spans the guides across y and
    ``x_start_m``..``x_end_m`` along x; it takes a frame ``rate_hz`` times a second and reports what it saw
    ``latency_s`` later, positions and lengths with Gaussian noise."""

    id: Id = Field(description=(
        "unique among conveyors, photo-eyes and cameras; names its plant ports (plant.<id>.count, .double, .lead_x, "
        ".lead_length, .lead_heading, .events)"))
    x_start_m: float = Field(ge=-100.0, le=1000.0, description="upstream edge of the field of view, on the line")
    x_end_m: float = Field(ge=-100.0, le=1000.0, description="downstream edge of the field of view, on the line")
    rate_hz: float = Field(30.0, ge=1.0, le=200.0, description="frames a second (industrial line cameras: 25-60)")
    latency_s: float = Field(0.04, ge=0.0, le=1.0, description=(
        "from a frame to its result on the camera's outputs (exposure, transfer, image processing)"))
    position_noise_m: float = Field(0.003, ge=0.0, le=0.1, description=(
        "standard deviation of every position and length the camera reports (independent per frame)"))
    double_gap_m: float = Field(0.05, ge=0.0, le=2.0, description=(
        "two fish in view whose extents along x overlap or are closer than this are a double"))


class Line(Strict):
    """Conveyors in flow order, side guides along the whole line, photo-eyes, cameras."""

    guide_width_m: float = Field(gt=0.05, le=5.0, description="side guides at y = +-guide_width_m/2")
    conveyors: list[Conveyor] = Field(min_length=1, max_length=64, description="the belts, in flow order")
    photoeyes: list[PhotoEye] = Field(default_factory=list, max_length=256, description="light beams across the line")
    cameras: list[Camera] = Field(default_factory=list, max_length=64, description=(
        "vision systems over the line (none in a file without the key)"))

    @pydantic.model_validator(mode="after")
    def _check_geometry(self) -> "Line":
        ids = [c.id for c in self.conveyors] + [p.id for p in self.photoeyes] + [c.id for c in self.cameras]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueAtKey("conveyors", "ids must be unique across conveyors, photo-eyes and cameras; repeated: "
                             f"{', '.join(dup)}")
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
        for i, c in enumerate(self.cameras):
            if not (self.x_start_m <= c.x_start_m < c.x_end_m <= self.x_end_m):
                raise ValueAtKey(f"cameras.{i}.x_end_m", f"cameras[{i}] ('{c.id}') sees x_start_m = {c.x_start_m:g} to "
                                 f"x_end_m = {c.x_end_m:g} m: it must be a stretch of the line [{self.x_start_m:g}, "
                                 f"{self.x_end_m:g}] m with x_start_m < x_end_m")
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
