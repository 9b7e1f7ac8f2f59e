"""The values the line's camera and device logs of a run may hold (``detections.csv``, ``rejections.csv`` of
contracts/measured-data.md), checked by :func:`plant.contract.measured.read_run` once the files are read as tables:
each problem an InputError naming the file, the row and the column."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from plant.contract.row_errors import fail_first, row_number
from plant.errors import InputError


def check_detections(log: pd.DataFrame, path: Path) -> None:
    """The values a camera logs: ``track`` a whole number from 1, ``heading`` -1, 0 (not known) or 1, ``double`` 0 or
    1, a fish's back not ahead of its front."""
    for column, bad, must in (
            ("track", (log["track"] % 1 != 0) | (log["track"] < 1), "a whole number from 1"),
            ("heading", ~log["heading"].isin([-1, 0, 1]), "-1 (tail first), 0 (not known) or 1 (head first)"),
            ("double", ~log["double"].isin([0, 1]), "0 or 1"),
            ("x_back_m", log["x_back_m"] > log["x_front_m"], "at most x_front_m (the fish's back is not ahead of its "
                                                             "front)")):
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
