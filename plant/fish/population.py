"""The fish of a run: sampled from the paper's statistics (a measured fish.csv is read into the same
:class:`FishSpec` by :func:`plant.contract.measured.fish_from_frame`).

A sampled fish's length is normal (mean, sd, clipped); height, width and weight follow the
length regressions of Table I *plus* a residual drawn with the spread of that fit, so that two
fish of one length differ as the measured ones do.  Where and when it is dropped follows the
drop pattern: ``bulk`` (a batch dumped onto the infeed in quick succession, as in the paper's
test) or ``sparse`` (one at a time at the infeed end).

>>> import numpy as np
>>> spec = PopulationSpec(count=3, seed_offset=0)
>>> fish = sample_fish(spec, infeed_x_m=(0.0, 2.0), half_width_m=0.25, rng=np.random.default_rng(1))
>>> [f.fish_id for f in fish], all(0.42 <= f.length_m <= 0.75 for f in fish)
(['f01', 'f02', 'f03'], True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from plant.fish.fish_data import length_regressions
from plant.validation import Strict

DEFAULT_HOURS_POST_MORTEM = 24.0
"""Hours since slaughter when a batch or a measured run does not say (unit: h): the paper's physical test used
fish dead for more than a day.  The one default: scenarios, re-simulated runs and calibration take it from here."""


@dataclass(frozen=True)
class FishSpec:
    """One fish: its size, its state, and where and when it is dropped (the columns of fish.csv)."""

    fish_id: str
    length_m: float
    height_m: float
    width_m: float
    weight_kg: float
    hours_post_mortem: float
    drop_t_s: float
    drop_x_m: float
    drop_y_m: float
    drop_yaw_rad: float
    drop_z_m: float
    """Height of the fish's lowest point above the belt at release."""
    side: int = 1
    """Which flank it lands on: +1 left flank down (local z up), -1 right flank down."""


class PopulationSpec(Strict):
    """The ``[fish]`` table of a scenario: how many fish, their sizes and how they are dropped."""

    count: int = Field(18, ge=1, le=2000, description="fish in the batch (the paper's test: 18)")
    length_mean_m: float = Field(0.60, gt=0.1, le=1.5, description=(
        "Table I mean (0.597 m); within [length_min_m, length_max_m]"))
    length_sd_m: float = Field(0.06, ge=0.0, le=0.5, description=(
        "spread of lengths in a graded batch (Table I: 0.085 m over a wider range)"))
    length_min_m: float = Field(0.42, gt=0.1, le=1.5, description="shortest fish of Table I")
    length_max_m: float = Field(0.75, gt=0.1, le=1.5, description=(
        "a little above the longest of Table I (0.68 m); every conveyor must be at least this long"))
    hours_post_mortem: float = Field(DEFAULT_HOURS_POST_MORTEM, ge=0.0, le=240.0, description=(
        "time since slaughter (unit: h); the paper's physical test used fish dead for more than a day"))
    drop: Literal["bulk", "sparse"] = Field("bulk", description=(
        "bulk: the batch dumped onto the infeed in quick succession; sparse: one at a time at the infeed end"))
    first_drop_s: float = Field(0.5, ge=0.0, le=3600.0, description=(
        "release of the first fish; the others follow every drop_interval_s"))
    drop_interval_s: float = Field(0.25, gt=0.0, le=600.0, description=(
        "time between releases (bulk: a dump takes a few seconds for 18 fish)"))
    drop_interval_jitter_s: float = Field(0.0, ge=0.0, le=300.0, description=(
        "each release moved by a uniform random time within +- this (unit: s), as fish arrive from a pump "
        "or a feeding belt; below half the interval, so fish keep their order"))
    drop_x_min_m: float | None = Field(None, description=(
        "drop zone along x (default: first 60 % of the first conveyor); give both ends or neither"))
    drop_x_max_m: float | None = Field(None, description="downstream end of the drop zone (see drop_x_min_m)")
    drop_height_m: float = Field(0.10, ge=0.0, le=2.0, description="lowest point of a fish above whatever is below it at release")
    yaw_spread_deg: float = Field(30.0, ge=0.0, le=180.0, description=(
        "bulk: headings spread this much around the flow direction (either way round); sparse: around head-first"))
    seed_offset: int = Field(0, ge=0, description="added to the run's seed for this population")

    @model_validator(mode="after")
    def _check(self) -> "PopulationSpec":
        if self.length_min_m > self.length_max_m:
            raise ValueError(f"length_min_m ({self.length_min_m}) is above length_max_m ({self.length_max_m})")
        if not (self.length_min_m <= self.length_mean_m <= self.length_max_m):
            raise ValueError(f"length_mean_m ({self.length_mean_m}) is outside [length_min_m, length_max_m]")
        if (self.drop_x_min_m is None) != (self.drop_x_max_m is None):
            raise ValueError("give both drop_x_min_m and drop_x_max_m, or neither")
        if self.drop_interval_jitter_s >= 0.5 * self.drop_interval_s and self.drop_interval_jitter_s > 0.0:
            raise ValueError(f"drop_interval_jitter_s ({self.drop_interval_jitter_s}) must be below half of "
                             f"drop_interval_s ({self.drop_interval_s}) so that fish keep their order")
        if self.drop_x_min_m is not None and self.drop_x_max_m is not None and self.drop_x_min_m > self.drop_x_max_m:
            raise ValueError("drop_x_min_m is above drop_x_max_m")
        return self


def fish_size(length_m: float, rng: np.random.Generator | None) -> tuple[float, float, float]:
    """(height, width, weight) for a length: regression plus a residual (none when rng is None)."""
    reg = length_regressions()
    h, w, m = float(reg.height_m(length_m)), float(reg.width_m(length_m)), float(reg.weight_kg(length_m))
    if rng is not None:
        h += rng.normal(0.0, reg.height_sd_m)
        w += rng.normal(0.0, reg.width_sd_m)
        m *= math.exp(rng.normal(0.0, reg.weight_log_sd))
    # keep the shape of a salmon: taller than thick, and not thinner than 6 % of its length
    w = max(w, 0.06 * length_m)
    h = max(h, 1.3 * w)
    return h, w, m


def lane_across(left_y_m: np.ndarray, right_y_m: np.ndarray) -> tuple[float, float]:
    """(centre y, half width) of the lane between the guides all along a stretch, from the guides' y along it (an
    off-centre lane: guides at y = -0.05 and -0.25 m give (-0.15, 0.1))."""
    lo, hi = float(np.max(right_y_m)), float(np.min(left_y_m))
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def tallest_fish_m(spec: PopulationSpec) -> float:
    """Height of the longest fish of ``spec`` by the regression: how wide a fish lying on its side is across."""
    return fish_size(spec.length_max_m, None)[0]


def sample_fish(spec: PopulationSpec, infeed_x_m: tuple[float, float], half_width_m: float,
                rng: np.random.Generator, centre_y_m: float = 0.0) -> list[FishSpec]:
    """Draw ``spec.count`` fish and their drops; ``infeed_x_m`` is the first conveyor's x range, the lane there
    ``centre_y_m +- half_width_m`` (:func:`lane_across`)."""
    lengths = np.clip(rng.normal(spec.length_mean_m, spec.length_sd_m, spec.count), spec.length_min_m, spec.length_max_m)
    x0, x1 = infeed_x_m
    zone = (spec.drop_x_min_m, spec.drop_x_max_m) if spec.drop_x_min_m is not None else (x0, x0 + 0.6 * (x1 - x0))
    # drawn after everything else, so that a batch without jitter is the same as before jitter existed
    fish = []
    for i, length in enumerate(lengths):
        length = float(length)
        h, w, m = fish_size(length, rng)
        if spec.drop == "sparse":
            yaw = math.radians(rng.uniform(-1, 1) * spec.yaw_spread_deg)
        else:
            yaw = math.radians(rng.uniform(-1, 1) * spec.yaw_spread_deg) + (math.pi if rng.random() < 0.5 else 0.0)
        # half-extents of the fish's footprint (length along its heading, height across) along x and y
        ext_x = 0.5 * length * abs(math.cos(yaw)) + 0.5 * h * abs(math.sin(yaw))
        ext_y = 0.5 * length * abs(math.sin(yaw)) + 0.5 * h * abs(math.cos(yaw))
        y_room = max(half_width_m - ext_y - 0.01, 0.0)
        lo = max(zone[0], x0) + ext_x + 0.03  # clear of the infeed end plate
        if spec.drop == "sparse":
            x = lo
            y = centre_y_m + rng.uniform(-0.3, 0.3) * y_room
        else:
            hi = max(zone[1] - 0.3 * ext_x, lo)
            x = rng.uniform(lo, hi)
            y = centre_y_m + rng.uniform(-1, 1) * y_room
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        fish.append(FishSpec(
            fish_id=f"f{i + 1:02d}", length_m=length, height_m=h, width_m=w, weight_kg=m,
            hours_post_mortem=spec.hours_post_mortem, drop_t_s=spec.first_drop_s + i * spec.drop_interval_s,
            drop_x_m=float(x), drop_y_m=float(y), drop_yaw_rad=float(yaw), drop_z_m=spec.drop_height_m,
            side=1 if rng.random() < 0.5 else -1))
    if spec.drop_interval_jitter_s > 0.0:
        shifts = rng.uniform(-spec.drop_interval_jitter_s, spec.drop_interval_jitter_s, len(fish))
        first = spec.first_drop_s
        fish = [replace(f, drop_t_s=max(first, f.drop_t_s + float(s))) for f, s in zip(fish, shifts)]
    return fish


def with_drop(f: FishSpec, **changes: float) -> FishSpec:
    """A copy of a fish with some drop values changed (e.g. raised to clear a pile)."""
    return replace(f, **changes)
