"""Fast tests of fishfmu.analysis.levels' responses on hand-made residuals (issue 16).

Two runs, each with two lag rows (a fish after a transfer) and one photo-eye row, simulated with every
level off and at a friction level of 1.4; the expected numbers are worked out in the comments.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.analysis.levels import DROP, LAG, MODELS, PASSAGE, fit_model, responses
from fishfmu.analysis.residuals import (BELT_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES, PASSAGE_RESIDUAL_DTYPES,
                                        RunResiduals, typed_frame)


def residuals(run_id: str, lags: list[float], dblocked: float) -> RunResiduals:
    rows = typed_frame([{"run_id": run_id, "fish_id": f"f{i}", "belt": 1, "conveyor_id": "b", "t_start_s": 1.0,
                         "t_end_s": 2.0, "offset_m": lag, "lag_m": lag, "heading": 1.0, "hours_post_mortem": 6.0,
                         "length_m": 0.6, "crowded": False, "n_samples": 10} for i, lag in enumerate(lags)],
                       BELT_RESIDUAL_DTYPES)
    passages = typed_frame([{"run_id": run_id, "sensor_id": "pe", "n": 5, "blocked_measured": 1.0,
                             "blocked_simulated": 1.0 + dblocked, "dblocked": dblocked, "se": 0.05}],
                           PASSAGE_RESIDUAL_DTYPES)
    return RunResiduals(run_id, rows, typed_frame([], PAIR_RESIDUAL_DTYPES), 0.0, passages=passages)


# level off: lags r1 (0.10, 0.20), r2 (0.30, 0.00); beams -0.10 (r1), -0.30 (r2)
# friction 1.4: every lag 0.10 m less, beams unchanged
OFF = {"r1": residuals("r1", [0.1, 0.2], -0.1), "r2": residuals("r2", [0.3, 0.0], -0.3)}
HIGH = {"r1": residuals("r1", [0.0, 0.1], -0.1), "r2": residuals("r2", [0.2, -0.1], -0.3)}
RESP = responses(OFF, {("friction", 1.4): HIGH}, {"r1": 6.0, "r2": 30.0})


def test_rows_and_kinds():
    assert list(RESP.row_kind) == [LAG, LAG, PASSAGE, LAG, LAG, PASSAGE]
    assert list(RESP.counts) == [2, 2]  # lag rows per run


def test_rows_are_weighted_by_their_noise():
    # a beam's weight is 1 / se^2 = 1 / 0.05^2 = 400; the lags' is 1 / their mean square at the best simulated
    # level: at off (0.01 + 0.04 + 0.09 + 0) / 4 = 0.035 m^2, at 1.4 (0 + 0.01 + 0.04 + 0.01) / 4 = 0.015 m^2.
    assert RESP.row_weight == pytest.approx([1 / 0.015, 1 / 0.015, 400.0] * 2)
    # r1 at off: lags (0.01 + 0.04) / 0.015; its beam less the beams' mean (-0.2): +0.1, so 0.01 x 400
    ss = RESP.run_ss({})
    assert ss[0] == pytest.approx(0.05 / 0.015 + 4.0)
    assert RESP.lag_ss({}) == pytest.approx([0.05, 0.09])
    # rows of other kinds can be left out (a model judged on what it changes): the beams weigh nothing then
    assert RESP.only((LAG,)).run_ss({})[0] == pytest.approx(0.05 / 0.015)


def test_a_common_beam_offset_is_no_error():
    # the beams' mean mismatch is the outline's, one offset for the line: shifting every beam row by the
    # same amount changes nothing
    shifted = responses({r: residuals(r, list(OFF[r].rows["lag_m"]), float(OFF[r].passages["dblocked"].iloc[0]) + 0.5)
                         for r in OFF}, {("friction", 1.4): HIGH}, {"r1": 6.0, "r2": 30.0})
    assert shifted.residuals({})[[2, 5]] == pytest.approx(RESP.residuals({})[[2, 5]])


def test_levels_interpolate_in_log_of_the_multiplier():
    # friction sqrt(1.4) is half-way between 1 and 1.4 in log: every lag 0.05 m less than at off
    half = np.full(2, np.sqrt(1.4))
    assert RESP.residuals({"friction": half})[[0, 1, 3, 4]] == pytest.approx([0.05, 0.15, 0.25, -0.05])
    # beyond the simulated values: held at the nearest end
    assert RESP.residuals({"friction": np.full(2, 3.0)})[[0, 1]] == pytest.approx([0.0, 0.1])


def test_constant_model_picks_the_level_that_fits_both_runs():
    # lags of both runs fall by 0.1 m between 1 and 1.4; the sum of squares is least where the mean lag
    # (0.15 at off) is gone, beyond 1.4: the grid's end, 1.4 (values outside are held at the end)
    fit = fit_model(MODELS["constant"], RESP, np.random.default_rng(0))
    assert fit.values["friction_level"] == pytest.approx(1.4)
    assert fit.values["joint_stiffening"] == 0.0  # rigor not simulated: off


def test_a_run_not_simulated_at_an_extended_value_is_held_at_its_own_end():
    # the grid extended to 2.0 for r1 alone (its own best lay at the end): r1's lags 0.05 m less again at 2.0;
    # r2, not simulated there, keeps its change at 1.4 (-0.1 m), not its lag at off
    r1_at_2 = {"r1": residuals("r1", [-0.05, 0.05], -0.1)}
    resp = responses(OFF, {("friction", 1.4): HIGH, ("friction", 2.0): r1_at_2}, {"r1": 6.0, "r2": 30.0})
    assert list(resp.values["friction"]) == [1.0, 1.4, 2.0]
    assert resp.residuals({"friction": np.full(2, 2.0)})[[0, 1, 3, 4]] == pytest.approx([-0.05, 0.05, 0.2, -0.1])


def test_a_gain_carried_by_one_run_is_told_as_such():
    from fishfmu.analysis.diagnose import CandidateFit
    # 8 of the 10 units of error removed come from r3: 80 %, more than half
    fit = CandidateFit("mucus_friction", 0.0, heldout_gain=0.3, heldout_gain_ci95=(-0.05, 0.5),
                       gain_by_run={"r1": 1.0, "r2": 1.0, "r3": 8.0})
    assert fit.carried_by() == ("r3", pytest.approx(0.8))
    # spread over the runs (4 of 10 at most), or too small a gain to matter: nothing to tell
    fit.gain_by_run = {"r1": 3.0, "r2": 3.0, "r3": 4.0}
    assert fit.carried_by() is None
    fit.gain_by_run, fit.heldout_gain = {"r1": 1.0, "r2": 1.0, "r3": 8.0}, 0.01
    assert fit.carried_by() is None


def with_drops(run_id: str, drops: list[float]) -> RunResiduals:
    """Fish alone after their drop (belt 0): a drop row each, no lag across a transfer."""
    rows = typed_frame([{"run_id": run_id, "fish_id": f"d{i}", "belt": 0, "conveyor_id": "a", "t_start_s": 1.0,
                         "t_end_s": 2.0, "offset_m": d, "lag_m": d, "heading": 1.0, "hours_post_mortem": 6.0,
                         "length_m": 0.6, "crowded": False, "n_samples": 10} for i, d in enumerate(drops)],
                       BELT_RESIDUAL_DTYPES)
    return RunResiduals(run_id, rows, typed_frame([], PAIR_RESIDUAL_DTYPES), 0.0)


def test_drop_rows_count_between_runs_only_and_weigh_by_their_scatter_within_a_run():
    # drops at off: r1 (0.04, 0.06), r2 (0.01, 0.03): every drop 0.02 m behind the data's in both (how a drop is
    # modelled), r1 0.03 m more (its fish slide longer). Friction 1.4 takes 0.02 m off every drop.
    off = {"r1": with_drops("r1", [0.04, 0.06]), "r2": with_drops("r2", [0.01, 0.03])}
    high = {"r1": with_drops("r1", [0.02, 0.04]), "r2": with_drops("r2", [-0.01, 0.01])}
    resp = responses(off, {("friction", 1.4): high}, {"r1": 1.0, "r2": 48.0})
    assert list(resp.row_kind) == [DROP] * 4 and list(resp.counts) == [0, 0]  # no lag rows
    # less their mean over the runs (0.035): r1 (0.005, 0.025), r2 (-0.025, -0.005)
    assert resp.residuals({}) == pytest.approx([0.005, 0.025, -0.025, -0.005])
    # noise: the scatter within a run, about each run's mean (0.01 m each side): variance 4 x 0.0001 / (4 - 2)
    assert resp.row_weight == pytest.approx([1 / 0.0002] * 4)
    # one friction level for both runs moves every drop alike: the difference between the runs stays
    assert resp.residuals({"friction": np.full(2, 1.4)}) == pytest.approx(resp.residuals({}))
    # r1 at 1.4 and r2 at 1: r1 (0.02, 0.04), r2 (0.01, 0.03), less their mean 0.025: the runs' means 0.01 m apart
    # instead of 0.03
    assert resp.residuals({"friction": np.array([1.4, 1.0])}) == pytest.approx([-0.005, 0.015, -0.015, 0.005])


def beam(run_id: str, measured: float, simulated: float) -> RunResiduals:
    """A run seen by one beam only: the mean blocked share of its passages of fish alone, measured and simulated;
    one lag row that no level changes."""
    r = residuals(run_id, [0.0], simulated - measured)
    r.passages["blocked_measured"], r.passages["blocked_simulated"] = measured, simulated
    return r


def test_rigor_held_out_runs_are_shown_measured_base_and_extended_as_the_beam_sees_them():
    # Four runs at 1, 24, 26 and 72 h. Measured: the beam blocked 0.9 of a passage by limp fish, 0.7 by the stiff
    # ones of 24 and 26 h (they flicker it). Our limp fish block 0.8 at every age; joints x21 stiffer (level 20)
    # block 0.6. A beam's offset (how it sees our outline) is its mean over the runs, so the base model, limp at
    # every age, is 0.8 everywhere. Each run held out, the others choose rigor x21 at its peak at 24 h, 10 h wide:
    # index at 1, 24, 26, 72 h = 0.00504, 1, 0.96079, 0; level 20 x index, interpolated in log(1 + level) between 0
    # and 20: changes -0.2 x (0.09607, 3.04452, 3.00647, 0) / 3.04452 = (-0.00631, -0.2, -0.19750, 0). Residuals
    # (-0.1, 0.1, 0.1, -0.1) plus these, less their mean (-0.10095): (-0.00536, 0.00095, 0.00345, 0.00095), and the
    # extended model is the measured share plus them.
    hours = {"a01": 1.0, "a24": 24.0, "a26": 26.0, "a72": 72.0}
    measured = {"a01": 0.9, "a24": 0.7, "a26": 0.7, "a72": 0.9}
    off = {r: beam(r, measured[r], 0.8) for r in hours}
    stiff = {r: beam(r, measured[r], 0.6) for r in hours}
    resp = responses(off, {("friction", 1.4): off, ("rigor", 20.0): stiff}, hours)  # friction changes nothing here
    cand = CANDIDATES["rigor_mortis"]
    cal = SimpleNamespace(responses=resp, baseline=list(off.values()))
    fit = cand.fit(cand, SimpleNamespace(cal=cal, rng=np.random.default_rng(0)))
    t = fit.side_by_side.set_index("run_id")
    assert list(t.index) == ["a01", "a24", "a26", "a72"] and list(t["covariate"]) == [1.0, 24.0, 26.0, 72.0]
    assert list(t["measured"]) == pytest.approx([0.9, 0.7, 0.7, 0.9])
    assert list(t["base"]) == pytest.approx([0.8] * 4)
    assert list(t["extended"]) == pytest.approx([0.89464, 0.70095, 0.70345, 0.90095], abs=1e-5)
    assert fit.heldout_gain > 0.99  # what is left: the tail of the bump at 1 h and the interpolation at 26 h
