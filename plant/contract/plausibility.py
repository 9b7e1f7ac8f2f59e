"""Physical plausibility of a measured run, checked by :func:`plant.contract.measured.read_run` (unless told
not to) before anything is simulated.

What is checked, and why: the format (:mod:`plant.contract.measured`) only knows that a value is a finite number;
a length typed in feet, a mass in grams, a drop outside the line or a drive log with a belt at 1e6 m/s
passes it, and the simulation would then run on nonsense (or blow up, or run for hours) instead of
refusing the input.  So a run must have

- fish sizes and weights a salmon can have (:func:`check_fish`, :func:`check_footprint`),
- drops within the conveyors' span, between the side guides (the whole dropped fish, not only its
  centre) and above a belt,
- every conveyor of the line in the drive log, at belt speeds (:func:`check_belts`),
- times from the run's start and within its drive log, and no more than :data:`MAX_RESIM_S` of
  simulated time per re-simulation (:func:`check_times`).

The bounds are the constants below, each with its reason; they are the only place these bounds are
stated.  They are generous: they catch typing errors, unit mix-ups and corrupt logs, not unusual fish.
Each refusal is an :class:`~plant.errors.InputError` naming the file, the row and the column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from plant.errors import InputError
from plant.fish.fish_data import length_regressions
from plant.contract.line import Line
from plant.contract.row_errors import first_row, refuse

LENGTH_RANGE_M = (0.2, 1.5)
"""Salmon length: the population model samples 0.42-0.75 m (Table I: 0.42-0.68 m) and a scenario allows
up to 1.5 m; below 0.2 m the length regressions give bodies thinner than a centimetre."""
WEIGHT_FACTOR = 3.0
"""Weight within this factor of the length-weight regression either way; the fit's residual sd is 6 %
(a factor 3 is 18 sd), the datasets seen so far lie within 0.90-1.15 of it: a mass typed in grams or
pounds, or a length in feet, is caught."""
HEIGHT_PER_LENGTH = (0.05, 0.6)
WIDTH_PER_LENGTH = (0.02, 0.4)
"""Body height and thickness as a fraction of length (Table I: about 0.24-0.29 and 0.10-0.14)."""
MAX_HOURS_POST_MORTEM = 10000.0
"""Hours since slaughter, in fish.csv and as ``hours_post_mortem`` of a ``[[runs]]`` entry (the schema,
:class:`plant.contract.measured.RunEntry`, uses this bound too): over a year, any real value fits."""
MAX_DROP_HEIGHT_M = 2.0
"""Height of a fish's lowest point above the belt at release: a fish dropped by hand or from a chute
falls at most this far (a 2 m fall lands at 6.3 m/s; the plant's health check stops at 25 m/s); the
scenario's ``fish.drop_height_m`` has the same bound."""
GUIDE_OVERLAP_M = 0.05
"""How far a dropped fish's footprint (its length along its heading, its height across) may reach into a
side guide: the camera is a few mm off and a fish bends, but a fish cannot lie across the guides (a
0.75 m fish crosswise in a 0.5 m channel is pushed off the line in the first second of the simulation)."""
MAX_BELT_SPEED_MPS = 10.0
"""|setpoint| and |speed| of a belt: singulation belts run at 0.3-2 m/s; 10 m/s is five times that."""
CLOCK_SLACK_S = 1.0
"""Tracks and photo-eye intervals may end this long after the drive log (clocks of different systems)."""
MAX_RESIM_S = 600.0
"""Simulated time of one re-simulation (the last drop, track sample or photo-eye interval, plus 1 s): a
measured batch lasts a minute (25-67 s in the datasets seen so far); 600 s of plant take several minutes
of one core, and diagnose re-simulates every run 10-20 times."""


def check_fish(fish: pd.DataFrame, path: Path, line: Line) -> None:
    """Sizes a salmon can have, drops within the line and above a belt."""
    length = fish["length_m"]
    lo, hi = LENGTH_RANGE_M
    i = first_row((length < lo) | (length > hi))
    if i is not None:
        refuse(path, i, "length_m", f"length_m = {length[i]:g} m is not a plausible salmon length "
                                    f"(allowed {lo:g} to {hi:g} m)")
    expected = pd.Series(np.asarray(length_regressions().weight_kg(length.to_numpy(float)), dtype=float),
                         index=fish.index)
    ratio = fish["weight_kg"] / expected
    i = first_row((ratio > WEIGHT_FACTOR) | (ratio < 1.0 / WEIGHT_FACTOR))
    if i is not None:
        e = expected[i]
        refuse(path, i, "weight_kg", f"weight_kg = {fish['weight_kg'][i]:g} kg is not plausible for a "
                                     f"{length[i]:g} m salmon: the length-weight regression gives {e:.3g} kg, and "
                                     f"{e / WEIGHT_FACTOR:.3g} to {e * WEIGHT_FACTOR:.3g} kg (a factor "
                                     f"{WEIGHT_FACTOR:g} either way) is allowed")
    for c, (a, b) in (("height_m", HEIGHT_PER_LENGTH), ("width_m", WIDTH_PER_LENGTH)):
        v = fish[c]
        i = first_row(v.notna() & ((v < a * length) | (v > b * length)))
        if i is not None:
            refuse(path, i, c, f"{c} = {v[i]:g} m is not plausible for a {length[i]:g} m salmon (allowed "
                               f"{a * length[i]:.3g} to {b * length[i]:.3g} m: {a:g} to {b:g} times its length)")
    h = fish["hours_post_mortem"]
    i = first_row(h.notna() & ((h < 0) | (h > MAX_HOURS_POST_MORTEM)))
    if i is not None:
        refuse(path, i, "hours_post_mortem", f"hours_post_mortem = {h[i]:g} must be between 0 (just slaughtered) "
                                             f"and {MAX_HOURS_POST_MORTEM:g}")
    x = fish["drop_x_m"]
    i = first_row((x < line.x_start_m) | (x > line.x_end_m))
    if i is not None:
        refuse(path, i, "drop_x_m", f"drop_x_m = {x[i]:g} m is outside the line: its conveyors span "
                                    f"x = {line.x_start_m:g} to {line.x_end_m:g} m")
    y = fish["drop_y_m"]
    left, right = line.guide_y_at(fish["drop_x_m"].to_numpy(float))
    i = first_row((y > left) | (y < right))
    if i is not None:
        refuse(path, i, "drop_y_m", f"drop_y_m = {y[i]:g} m is outside the side guides (y = {right[i]:g} to "
                                    f"{left[i]:g} m there)")
    z = fish["drop_z_m"]
    i = first_row((z < 0) | (z > MAX_DROP_HEIGHT_M))
    if i is not None:
        where = "below the belt top" if z[i] < 0 else "too high"
        refuse(path, i, "drop_z_m", f"drop_z_m = {z[i]:g} m is {where}: the height of the fish's lowest point "
                                    f"above the belt at release must be between 0 (lying on it) and "
                                    f"{MAX_DROP_HEIGHT_M:g} m")


def check_footprint(fish: pd.DataFrame, path: Path, line: Line) -> None:
    """A dropped fish fits between the guides (with heights filled in from the regressions)."""
    yaw = fish["drop_yaw_rad"]
    spread = 0.5 * fish["length_m"] * np.abs(np.sin(yaw)) + 0.5 * fish["height_m"] * np.abs(np.cos(yaw))
    left, right = line.guide_y_at(fish["drop_x_m"].to_numpy(float))
    into = np.maximum(fish["drop_y_m"] + spread - left, right - (fish["drop_y_m"] - spread))
    i = first_row(into > GUIDE_OVERLAP_M)
    if i is not None:
        refuse(path, i, "drop_y_m", f"a {fish['length_m'][i]:g} m fish at drop_y_m = {fish['drop_y_m'][i]:g} m "
                                    f"with drop_yaw_rad = {yaw[i]:g} would reach {into[i]:.3f} m into a "
                                    f"side guide (at y = {right[i]:g} and {left[i]:g} m there; at most "
                                    f"{GUIDE_OVERLAP_M:g} m is allowed): it cannot lie there")


def check_belts(belts: pd.DataFrame, path: Path, line: Line) -> None:
    """Every conveyor logged, speeds a belt can run at."""
    logged = set(belts["conveyor_id"].unique())
    missing = [c.id for c in line.conveyors if c.id not in logged]
    if missing:
        raise InputError(f"no rows for conveyor{'s' if len(missing) > 1 else ''} {', '.join(missing)}: every "
                         "conveyor of the line must be in the drive log (an unlogged belt cannot be re-simulated)",
                         file=path, where="column conveyor_id")
    for c in ("setpoint_mps", "speed_mps"):
        i = first_row(belts[c].abs() > MAX_BELT_SPEED_MPS)
        if i is not None:
            refuse(path, i, c, f"{c} = {belts[c][i]:g} m/s is not a belt speed (|speed| at most "
                               f"{MAX_BELT_SPEED_MPS:g} m/s)")


def check_times(run_id: str, *tables: tuple[pd.DataFrame, Path]) -> None:
    """Times from the run's start, within the drive log, and a re-simulation of bounded length.

    ``tables``: (fish, tracks, photoeyes, belts), each with its file."""
    (fish, fish_file), (tracks, tracks_file), (pe, pe_file), (belts, belts_file) = tables
    log_end = float(belts["t_s"].max())
    checks = [(fish, fish_file, "drop_t_s", log_end), (tracks, tracks_file, "t_s", log_end + CLOCK_SLACK_S),
              (pe, pe_file, "t_on_s", log_end + CLOCK_SLACK_S), (pe, pe_file, "t_off_s", log_end + CLOCK_SLACK_S),
              (belts, belts_file, "t_s", np.inf)]
    for df, path, c, limit in checks:
        t = df[c]
        i = first_row(t < 0)
        if i is not None:
            refuse(path, i, c, f"{c} = {t[i]:g} s is before the run's start (times are seconds from it, >= 0)")
        i = first_row(t > limit)
        if i is not None:
            slack, why = (("", "belt speeds are known only while they were logged") if c == "drop_t_s" else
                          (f" by more than {CLOCK_SLACK_S:g} s", "what a run records must lie within its drive log"))
            refuse(path, i, c, f"{c} = {t[i]:g} s is after the end of the drive log{slack} (belts.csv ends at "
                               f"t_s = {log_end:g} s): {why}")
    # what a re-simulation covers (fishfmu.analysis.resim.run_duration_s): the last drop, track sample or interval end
    for df, path, c in ((fish, fish_file, "drop_t_s"), (tracks, tracks_file, "t_s"), (pe, pe_file, "t_off_s")):
        i = first_row(df[c] + 1.0 > MAX_RESIM_S)
        if i is not None:
            refuse(path, i, c, f"{c} = {df[c][i]:g} s: re-simulating run '{run_id}' would simulate more than "
                               f"{MAX_RESIM_S:g} s, the limit per re-simulation (a measured batch takes about a "
                               "minute); split the run")
