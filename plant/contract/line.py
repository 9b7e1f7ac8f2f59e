"""The line: conveyors, side guides (straight or polylines), photo-eyes and cameras, as the ``[line]`` table
describes them.

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

import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
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
        "height of the top surface at the belt's upstream end; a conveyor may step down from where the one before "
        "ends, by at most 0.5 m, not up"))
    incline_deg: float = Field(0.0, ge=-30.0, le=30.0, description=(
        "slope of the belt along x (positive: it climbs downstream); length_m stays measured along x, the "
        "downstream end is length_m tan(incline) higher"))

    @property
    def x_end_m(self) -> float:
        return self.x_start_m + self.length_m

    @property
    def z_end_m(self) -> float:
        """Height of the top surface at the downstream end."""
        return self.z_top_m + self.length_m * math.tan(math.radians(self.incline_deg))

    def z_at(self, x_m: float) -> float:
        """Height of the top surface at x (held at the ends' heights beyond them)."""
        return self.z_top_m + (min(max(x_m, self.x_start_m), self.x_end_m) - self.x_start_m) * math.tan(
            math.radians(self.incline_deg))


class PhotoEye(Strict):
    """A light beam across the line (along y) at x, height z: blocked when a fish is in it."""

    id: Id = Field(description="unique among conveyors and photo-eyes; its plant port is plant.<id>.blocked")
    x_m: float = Field(ge=-100.0, le=1000.0, description="position of the beam along the line, between its ends")
    z_m: float = Field(ge=-10.0, le=10.0, description=(
        "beam height (absolute z): above the belt top there, by at most 0.5 m"))
    latency_s: float = Field(0.0, ge=0.0, le=1.0, exclude_if=lambda v: v == 0.0, description=(  # 0: files as before
        "how late the beam's blocked signal reports its edges, on and off alike (an input filter, a slow input card "
        "or scan); rounded to the plant's communication step"))


Point = Annotated[list[float], Field(min_length=2, max_length=2)]
"""(x_m, y_m): TOML has arrays, not tuples."""


class Guides(Strict):
    """Side guides as polylines seen from above (a funnel, a flare): (x, y) points with x increasing; before the
    first point and after the last a guide runs straight on.  Without them, straight guides at
    ``y = +-guide_width_m/2``."""

    left: list[Point] = Field(min_length=1, max_length=256, description=(
        "the left guide (y > 0 side, looking downstream) as (x_m, y_m) points, x increasing"))
    right: list[Point] = Field(min_length=1, max_length=256, description=(
        "the right guide (y < 0 side) as (x_m, y_m) points, x increasing"))


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


class Part(Strict):
    """A fixed part of the line read from an STL file (a chute, a deflector plate): static contact geometry that
    fish slide on like the guides (fish-guide friction).  Its triangles' normals must face where fish come from."""

    id: Id = Field(description="unique among the line's items")
    stl: str = Field(min_length=1, description=(
        "the STL file (ASCII or binary, a regular file of at most 64 MB); relative to the scenario or dataset file "
        "that names it; all parts of a line together at most 100 000 triangles"))
    scale: float = Field(1.0, gt=0.0, le=1.0, description="metres per STL unit (0.001 for a file in millimetres)")
    offset_m: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3, description=(
        "where the STL's origin sits in the line frame (x, y, z)"))


class Device(Strict):
    """An actuated device that takes fish off the line (see :mod:`plant.contract.devices` for its shape and motion):

    - ``gate``: a flap bridging a transfer gap, hinged at its upstream edge; open, it swings down by ``travel_deg``
      and fish drop through the gap into a bin below;
    - ``pusher``: a paddle behind the guide opposite ``side`` that strokes ``travel_m`` across the belt and pushes a
      fish out through an opening in the guide on ``side``;
    - ``diverter``: an arm that is the guide on ``side`` from ``x_m`` to ``x_m + length_m`` at rest, pivoting at its
      downstream end; swung ``travel_deg`` into the lane, it blocks the lane and steers fish out through the
      opening it leaves in the guide.

    Its actuator moves at constant speed, the whole travel in ``stroke_s``, towards the end its command asks for
    (true: open, stroke, swing; false: back home)."""

    id: Id = Field(description=(
        "unique among the line's items; names its plant ports (plant.<id>.command in; .position, .at_home, .at_end, "
        ".rejected out)"))
    kind: Literal["gate", "pusher", "diverter"] = Field(description="what it is (see above)")
    x_m: float = Field(ge=-100.0, le=1000.0, description=(
        "gate: its hinge, at or after the end of a conveyor; pusher: upstream end of the paddle; diverter: upstream "
        "(free) end of the arm at rest"))
    length_m: float = Field(gt=0.05, le=3.0, description=(
        "along x: the gate's flap (it must fit in the gap before the next conveyor), the pusher's paddle and its "
        "opening, the diverter's arm"))
    side: Literal["left", "right"] = Field("right", description=(
        "pusher and diverter: the side fish leave by (y > 0 is left, looking downstream); a gate drops them below"))
    stroke_s: float = Field(0.25, ge=0.02, le=10.0, description="time for the whole travel, each way")
    travel_deg: float | None = Field(None, gt=0.0, le=90.0, description=(
        "gate: how far the flap swings down open (default 60); diverter: how far the arm swings into the lane "
        "(default 45); not for a pusher"))
    travel_m: float | None = Field(None, gt=0.0, le=5.0, description=(
        "pusher: its stroke across the belt (default: the lane's width there); not for a gate or diverter"))

    @property
    def x_end_m(self) -> float:
        return self.x_m + self.length_m


class Line(Strict):
    """Conveyors in flow order, side guides along the whole line, photo-eyes, cameras, devices."""

    guide_width_m: float = Field(gt=0.05, le=5.0, description="side guides at y = +-guide_width_m/2")
    conveyors: list[Conveyor] = Field(min_length=1, max_length=64, description="the belts, in flow order")
    photoeyes: list[PhotoEye] = Field(default_factory=list, max_length=256, description="light beams across the line")
    cameras: list[Camera] = Field(default_factory=list, max_length=64, description=(
        "vision systems over the line (none in a file without the key); a scenario's cameras must not be able to log "
        "more than fishfmu reads back (detections.csv of at most 512 MB: frames x fish.count rows of ~200 bytes)"))
    parts: list[Part] = Field(default_factory=list, max_length=64, description=(
        "fixed parts from STL files (none in a file without the key)"))
    devices: list[Device] = Field(default_factory=list, max_length=32, description=(
        "reject gates, pushers and diverters (none in a file without the key)"))
    guides: Guides | None = Field(None, description=(
        "side guides as polylines (a funnel narrowing towards a belt's end); without it straight at "
        "+-guide_width_m/2, which stays the widest they may get"))

    @pydantic.model_validator(mode="after")
    def _check_geometry(self) -> "Line":
        ids = ([c.id for c in self.conveyors] + [p.id for p in self.photoeyes] + [c.id for c in self.cameras]
               + [p.id for p in self.parts] + [d.id for d in self.devices])
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueAtKey("conveyors", "ids must be unique across conveyors, photo-eyes, cameras, parts and devices; "
                             "repeated: "
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
            if b.z_top_m > a.z_end_m + 1e-3:
                raise ValueAtKey(f"conveyors.{i + 1}.z_top_m",
                    f"conveyors[{i + 1}] ('{b.id}') top z_top_m = {b.z_top_m} is above where '{a.id}' ends "
                    f"({a.z_end_m:g}): a step up stops fish; only steps down are supported")
            if a.z_end_m - b.z_top_m > 0.5:
                raise ValueAtKey(f"conveyors.{i + 1}.z_top_m", f"step down of {a.z_end_m - b.z_top_m:.3f} m from '{a.id}' to '{b.id}' "
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
        if self.guides is not None:
            half = 0.5 * self.guide_width_m
            for side, points in (("left", self.guides.left), ("right", self.guides.right)):
                x = [p[0] for p in points]
                for j in range(1, len(x)):
                    if x[j] <= x[j - 1]:
                        raise ValueAtKey(f"guides.{side}.{j}", f"guides.{side}[{j}] at x = {x[j]:g} m is not after the "
                                         f"point before it (x = {x[j - 1]:g} m): x must increase along a guide")
                for j, (px, py) in enumerate(points):
                    if abs(py) > half + 1e-9:
                        raise ValueAtKey(f"guides.{side}.{j}", f"guides.{side}[{j}] at y = {py:g} m is outside "
                                         f"guide_width_m = {self.guide_width_m:g} (+-{half:g} m): the belts are only "
                                         "known to be that wide")
            xs = sorted({p[0] for p in self.guides.left} | {p[0] for p in self.guides.right})
            left, right = self.guide_y_at(np.array(xs))
            narrow = np.flatnonzero(left - right < 0.1 - 1e-9)
            if len(narrow):
                k = int(narrow[0])
                raise ValueAtKey("guides", f"at x = {xs[k]:g} m the guides are {left[k] - right[k]:.3f} m apart (left "
                                 f"y = {left[k]:g}, right y = {right[k]:g}): at least 0.1 m, left of right")
        for i, c in enumerate(self.cameras):
            if not (self.x_start_m <= c.x_start_m < c.x_end_m <= self.x_end_m):
                raise ValueAtKey(f"cameras.{i}.x_end_m", f"cameras[{i}] ('{c.id}') sees x_start_m = {c.x_start_m:g} to "
                                 f"x_end_m = {c.x_end_m:g} m: it must be a stretch of the line [{self.x_start_m:g}, "
                                 f"{self.x_end_m:g}] m with x_start_m < x_end_m")
        for i, d in enumerate(self.devices):
            self._check_device(i, d)
        return self

    def _check_device(self, i: int, d: Device) -> None:
        name = f"devices[{i}] ('{d.id}')"
        unused = "travel_m" if d.kind != "pusher" else "travel_deg"
        if getattr(d, unused) is not None:
            raise ValueAtKey(f"devices.{i}.{unused}", f"{name} is a {d.kind}: it has no {unused} "
                             f"({'travel_deg' if unused == 'travel_m' else 'travel_m'} sets its travel)")
        if d.kind == "gate":
            gap = next(((a, b) for a, b in zip(self.conveyors, self.conveyors[1:])
                        if a.x_end_m - 1e-9 <= d.x_m < b.x_start_m), None)
            if gap is None or d.x_end_m > gap[1].x_start_m + 1e-9:
                raise ValueAtKey(f"devices.{i}.x_m", f"{name}: a gate's flap (x_m = {d.x_m:g} to {d.x_end_m:g} m) "
                                 "must lie in the gap between two conveyors (gaps up to 0.5 m)")
        elif not (self.x_start_m <= d.x_m and d.x_end_m <= self.x_end_m):
            raise ValueAtKey(f"devices.{i}.x_m", f"{name} spans x = {d.x_m:g} to {d.x_end_m:g} m: it must be over the "
                             f"line [{self.x_start_m:g}, {self.x_end_m:g}] m")

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

    def with_parts_relative_to(self, folder: Path) -> "Line":
        """The line with each part's relative ``stl`` path made absolute against ``folder`` (the folder of the
        scenario or dataset file that names it)."""
        if not any(not Path(p.stl).is_absolute() for p in self.parts):
            return self
        parts = [p.model_copy(update={"stl": str((folder / p.stl).resolve())}) if not Path(p.stl).is_absolute() else p
                 for p in self.parts]
        return self.model_copy(update={"parts": parts})

    def guide_y_at(self, x_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(left y, right y) of the side guides at each x (straight on beyond their first and last points)."""
        x = np.asarray(x_m, dtype=float)
        if self.guides is None:
            half = 0.5 * self.guide_width_m
            return np.full(x.shape, half), np.full(x.shape, -half)
        left, right = (np.array(g, dtype=float).reshape(-1, 2) for g in (self.guides.left, self.guides.right))
        return np.interp(x, left[:, 0], left[:, 1]), np.interp(x, right[:, 0], right[:, 1])

    def z_top_at(self, x_m: float) -> float:
        """Height of the belt top under x (in a gap: the downstream belt's start)."""
        return self.conveyor_at(x_m).z_at(x_m)

    @property
    def z_range_m(self) -> tuple[float, float]:
        """Lowest and highest point of the belts' top surfaces."""
        z = [z for c in self.conveyors for z in (c.z_top_m, c.z_end_m)]
        return min(z), max(z)

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
