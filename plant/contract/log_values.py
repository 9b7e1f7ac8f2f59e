"""The values the line's camera and device logs of a run may hold (``detections.csv``, ``rejections.csv`` of
contracts/measured-data.md), checked by :func:`plant.contract.measured.read_run` once the files are read as tables:
each problem an InputError naming the file, the row and the column; and the most bytes a run's ``detections.csv``
can take, so that a scenario whose cameras would log more than fishfmu reads back is refused before it runs."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from plant.contract.row_errors import fail_first, row_number
from plant.errors import InputError


BACK_AHEAD_SIGMAS = 6.0 * math.sqrt(2.0)
"""How far a logged back may lie ahead of the front, in the camera's ``position_noise_m``: the two carry independent
noise (their difference sigma * sqrt(2)), so a fish's back ahead of its front by more than six of those is not noise."""


def check_detections(log: pd.DataFrame, path: Path, position_noise_m: dict[str, float]) -> None:
    """The values a camera logs: ``track`` a whole number from 1, ``heading`` -1, 0 (not known) or 1, ``double`` 0 or
    1, a fish's back not ahead of its front by more than its camera's noise allows (``position_noise_m`` by camera id:
    :data:`BACK_AHEAD_SIGMAS`)."""
    slack = log["camera_id"].map(position_noise_m).fillna(0.0) * BACK_AHEAD_SIGMAS
    for column, bad, must in (
            ("track", (log["track"] % 1 != 0) | (log["track"] < 1), "a whole number from 1"),
            ("heading", ~log["heading"].isin([-1, 0, 1]), "-1 (tail first), 0 (not known) or 1 (head first)"),
            ("double", ~log["double"].isin([0, 1]), "0 or 1"),
            ("x_back_m", log["x_back_m"] > log["x_front_m"] + slack,
             "at most x_front_m (a fish's back is not ahead of its front by more than its camera's position noise)")):
        if bad.any():
            fail_first(bad, path, column, f"{column} = {log[column][bad].iloc[0]:g}: must be {must}")


def check_rejections(log: pd.DataFrame, n_fish: int, path: Path) -> None:
    """No fish taken off twice (an empty ``fish_id``, not known, may repeat), no more rejections than the run's
    ``n_fish`` fish."""
    known = log["fish_id"].notna()
    twice = known & log["fish_id"].duplicated()
    if twice.any():
        fish_id = log["fish_id"][twice].iloc[0]
        first = log.index[(log["fish_id"] == fish_id).to_numpy()][0]
        fail_first(twice, path, "fish_id", f"fish '{fish_id}' is rejected twice (also in row {row_number(first)}): a "
                                           "fish leaves the line once")
    if len(log) > n_fish:
        raise InputError(f"{len(log)} rejections but the run has {n_fish} fish in fish.csv: a fish is taken off "
                         "the line at most once", file=path, where=f"row {row_number(log.index[n_fish])}")


NUMBER_CHARS = 24
"""The most characters a number of a written log takes: Python's repr of a float (sign, 17 significant digits, point,
exponent: ``-1.2345678901234567e-308``), which pandas writes; an integer column written as floats stays within it."""
DETECTIONS_HEADER_BYTES = 100
"""``t_s,camera_id,track,x_back_m,x_front_m,y_m,length_m,heading,double`` and its line break (70 bytes), rounded up."""


def detection_row_bytes(camera_id: str) -> int:
    """The most bytes one row of ``detections.csv`` takes: eight numbers, the camera's id, eight commas, a line
    break (ids need no quoting: the schema's Id pattern)."""
    return 8 * NUMBER_CHARS + len(camera_id.encode()) + 8 + 1


def detections_bytes_bound(cameras: list, duration_s: float, n_fish: int) -> int:
    """The most bytes a run's ``detections.csv`` can take: each camera takes at most ``rate_hz * duration_s + 1``
    frames (one at ``k / rate_hz``) and logs one row per fish in view, at most every fish of the run."""
    frames = [math.floor(c.rate_hz * duration_s) + 1 for c in cameras]
    return DETECTIONS_HEADER_BYTES + sum(f * n_fish * detection_row_bytes(c.id) for f, c in zip(frames, cameras))
