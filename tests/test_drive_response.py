"""The drives' response calibrated on their start-ups: ramps recovered from logs of known ramps, and on the
independent simulator's logs (its drives are not ours: they follow a step as a lag, not a ramp) the fitted
ramps bring the start-ups of runs they never saw closer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.contract.measured import FISH, Dataset, Run, empty_table, read_dataset

from fishfmu.analysis.drive_response import STARTUP_MAX_S, fit_drive_responses, startup
from fishfmu.analysis.resim import simulate_drive
from fishfmu.analysis.synthetic import SMALL_KPI, SMALL_LINE
from fishfmu.fmu.archive import open_fmu
from fishfmu.fmu.build import builtin_fmu

DEV_NONE = Path(__file__).resolve().parents[2] / "shared" / "data" / "dev" / "dev_none"
TRUE_RAMPS = {"c1": 0.6, "c2": 2.0, "c3": 5.0}
"""m/s^2: slower, as, and faster than the built-in drive's 2 m/s^2."""


def _logged_startups(n_runs: int, rng: np.random.Generator) -> Dataset:
    """Runs whose drive logs are the built-in drive at ``TRUE_RAMPS`` starting from rest to setpoints that differ
    from run to run, logged at 100 Hz with 3 mm/s of noise; the first fish lands at 2.5 s."""
    t = np.round(np.arange(0.0, 6.0, 0.01), 2)
    fish = empty_table(FISH)
    fish.loc[0] = {"fish_id": "f01", "length_m": 0.6, "weight_kg": 2.0, "drop_t_s": 2.5, "drop_x_m": 0.4,
                   "drop_y_m": 0.0, "drop_yaw_rad": 0.0}
    runs = []
    with open_fmu(builtin_fmu("conveyor_drive")) as fmu:
        for k in range(n_runs):
            rows = []
            for c, base in zip(TRUE_RAMPS, (0.3, 0.7, 1.2)):
                sp = np.where(t >= 0.2, base * rng.uniform(0.8, 1.2), 0.0)
                v = simulate_drive(fmu, c, t, sp, np.zeros_like(t), 0.0, {"ramp_acceleration": TRUE_RAMPS[c]})
                rows.append(pd.DataFrame({"t_s": t, "conveyor_id": c, "setpoint_mps": sp,
                                          "speed_mps": v + rng.normal(0.0, 0.003, len(t))}))
            runs.append(Run(f"r{k:02d}", 10.0, "", fish.copy(), belts=pd.concat(rows, ignore_index=True)))
    return Dataset("startups", "", SMALL_LINE, SMALL_KPI, runs)


def test_a_startup_is_cut_where_the_first_fish_lands() -> None:
    ds = _logged_startups(1, np.random.default_rng(0))
    t, sp, v = startup(ds.runs[0], "c2")
    assert t[0] == pytest.approx(0.19) and t[-1] == pytest.approx(2.5)  # the drop, before STARTUP_MAX_S ends it
    assert t[-1] - t[0] < STARTUP_MAX_S
    assert sp[0] == 0.0 and sp[-1] > 0.5  # from the sample before the step


def test_ramps_of_drives_that_differ_from_the_model_are_recovered_within_their_intervals() -> None:
    """With the drive's own model and white noise the interval (a bootstrap over runs) is narrow, 1 % or less; the
    fit's own resolution (a parabola through ramps 9 % apart) is about 0.2 %, which the interval is allowed."""
    ds = _logged_startups(8, np.random.default_rng(1))
    fits = {f.conveyor_id: f for f in fit_drive_responses(ds, [r.id for r in ds.runs[:6]], np.random.default_rng(2))}
    for c in ("c1", "c3"):  # slower and faster than the model: found, kept, and the held-out runs fit better
        f = fits[c]
        assert f.ci95[0] <= TRUE_RAMPS[c] * 1.002 and f.ci95[1] >= TRUE_RAMPS[c] * 0.998, (c, f)
        assert f.ci95[1] - f.ci95[0] < 0.02 * TRUE_RAMPS[c]
        assert f.fitted_mps2 == pytest.approx(TRUE_RAMPS[c], rel=0.005)
        assert f.kept and f.value_mps2 == pytest.approx(TRUE_RAMPS[c], rel=0.005)
        assert f.rms_mps["heldout"]["after"] < 0.3 * f.rms_mps["heldout"]["before"]
        assert f.rms_mps["heldout"]["after"] < 0.006  # down to about the logs' noise (3 mm/s)
    assert fits["c2"].fitted_mps2 == pytest.approx(2.0, rel=0.05)
    assert not fits["c2"].kept and fits["c2"].value_mps2 == 2.0  # the model's ramp already: nothing to gain


@pytest.mark.skipif(not DEV_NONE.is_dir(), reason="needs ../shared/data/dev")
def test_on_the_independent_simulators_logs_the_fitted_ramps_carry_over_to_runs_never_seen() -> None:
    """Its drives reach half a step in about 0.2 s and 90 % in 0.7 s, whatever the step: a slow belt (c1, 0.25
    m/s) comes up to speed slower than our 2 m/s^2 ramp takes it, a fast one (c4, 1.25 m/s) faster."""
    ds = read_dataset(DEV_NONE)
    sparse = [r.id for r in ds.runs if "sparse" in r.notes]
    fits = {f.conveyor_id: f for f in fit_drive_responses(ds, sparse, np.random.default_rng(0))}
    assert fits["c1"].kept and fits["c1"].value_mps2 < 1.0
    assert fits["c4"].kept and fits["c4"].value_mps2 > 2.0
    for c in ("c1", "c2", "c4"):  # the bulk runs' start-ups, never fitted on, come closer
        assert fits[c].rms_mps["heldout"]["after"] < 0.7 * fits[c].rms_mps["heldout"]["before"]
