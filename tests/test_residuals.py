"""Fast tests of fishfmu.analysis.residuals on small hand-made frames (issue 14).

Every frame here has a few rows built in the test; the expected values are worked out by hand in
the comments.  The slow hidden-effect tests cover the same functions end to end.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from fishfmu.analysis.residuals import (BELT_RESIDUAL_DTYPES, DRIVE_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES,
                               PASSAGE_RESIDUAL_DTYPES, TRACK_ERROR_DTYPES, alone, belt_residuals, concat_typed,
                               pair_residuals, passage_residuals,
                               photoeye_passages, track_errors, typed_frame, MIN_PASSAGE_SE, RunResiduals)
from fishfmu.analysis.drive_response import drive_residuals, drive_residuals_averaged
from plant.contract.line import Line
from plant.contract.measured import Run

# Two belts end to end: "a" from x = 0 to 2 m, "b" from 2 to 6 m (the transfer at x = 2).
LINE = Line.model_validate({
    "guide_width_m": 0.5,
    "conveyors": [
        {"id": "a", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
        {"id": "b", "x_start_m": 2.0, "length_m": 4.0, "width_m": 0.5, "z_top_m": 0.0},
    ],
    "photoeyes": [{"id": "pe", "x_m": 4.0, "z_m": 0.015}],
})


def track(fid: str, t, x, y=0.0, yaw=0.0) -> pd.DataFrame:
    t = np.asarray(t, float)
    return pd.DataFrame({"t_s": t, "fish_id": fid, "x_m": np.broadcast_to(np.asarray(x, float), t.shape),
                         "y_m": np.broadcast_to(np.asarray(y, float), t.shape),
                         "yaw_rad": np.broadcast_to(np.asarray(yaw, float), t.shape)})


def fish_table(*rows: dict) -> pd.DataFrame:
    base = {"length_m": 0.6, "weight_kg": 2.0, "height_m": 0.10, "width_m": 0.06, "hours_post_mortem": np.nan,
            "drop_t_s": 0.0, "drop_x_m": 0.3, "drop_y_m": 0.0, "drop_yaw_rad": 0.0, "drop_z_m": 0.05}
    return pd.DataFrame([{**base, **r} for r in rows])


def make_run(fish: pd.DataFrame, tracks: pd.DataFrame, hours: float | None = 6.0) -> Run:
    return Run(id="r01", hours_post_mortem=hours, notes="", fish=fish, tracks=tracks)


def assert_dtypes(df: pd.DataFrame, dtypes: dict) -> None:
    assert list(df.columns) == list(dtypes)
    for c, t in dtypes.items():
        assert df[c].dtype == np.dtype(t), (c, df[c].dtype, t)


# --------------------------------------------------------------------------------------------------
# track_errors
# --------------------------------------------------------------------------------------------------

def test_track_errors_constant_offset_in_x():
    # Measured at 0, 0.04, ..., 0.40 s moving at 0.5 m/s; the simulation is the same track 0.1 m
    # further along x, sampled on another grid (0.02, 0.07, ...) so it must be interpolated.
    tm = np.arange(11) * 0.04
    ts = 0.02 + np.arange(-1, 10) * 0.05            # -0.03 .. 0.47: covers every measured sample
    m = track("f1", tm, 0.3 + 0.5 * tm, y=0.01, yaw=0.2)
    s = track("f1", ts, 0.3 + 0.5 * ts + 0.1, y=0.01, yaw=0.2)
    e = track_errors(m, s)
    assert_dtypes(e, TRACK_ERROR_DTYPES)
    assert len(e) == 11
    np.testing.assert_allclose(e["t_s"], tm)
    np.testing.assert_allclose(e["x_m"], 0.3 + 0.5 * tm)      # the measured position is carried
    np.testing.assert_allclose(e["ex_m"], 0.1, atol=1e-12)     # (x + 0.1) - x = 0.1 at every sample
    np.testing.assert_allclose(e["ey_m"], 0.0, atol=1e-12)
    np.testing.assert_allclose(e["eyaw_rad"], 0.0, atol=1e-12)
    # Simulated minus measured, not the other way round: swapping gives -0.1.
    np.testing.assert_allclose(track_errors(s.assign(x_m=0.3 + 0.5 * ts), m.assign(x_m=0.2 + 0.5 * tm))["ex_m"],
                               -0.1, atol=1e-12)


def test_track_errors_time_shift_gives_lag_at_belt_speed():
    # Belt at v = 0.8 m/s; the simulated fish passes every point 0.25 s later than the measured one:
    # x_sim(t) = x_meas(t - 0.25), so ex = -v * 0.25 = -0.2 m at every sample.
    v, shift = 0.8, 0.25
    tm = np.arange(1.0, 2.01, 0.04)
    ts = np.arange(0.5, 2.51, 0.03)
    m = track("f1", tm, 0.2 + v * tm)
    s = track("f1", ts, 0.2 + v * (ts - shift))
    e = track_errors(m, s)
    assert len(e) == len(tm)
    np.testing.assert_allclose(e["ex_m"], -0.2, atol=1e-12)


def test_track_errors_heading_wraps_to_the_short_way_round():
    # Measured yaw -3.1 rad, simulated +3.1 rad: 6.2 rad apart one way, 2*pi - 6.2 the other;
    # eyaw = sim - meas wrapped to (-pi, pi] = 6.2 - 2*pi = -0.0832 rad (not +6.2).
    tm = np.array([0.0, 0.04, 0.08])
    e = track_errors(track("f1", tm, 1.0, yaw=-3.1), track("f1", tm, 1.0, yaw=3.1))
    np.testing.assert_allclose(e["eyaw_rad"], 6.2 - 2 * math.pi, atol=1e-12)


def test_track_errors_gaps_and_ends():
    # The simulated track has samples at 0.0 .. 1.0 and 2.0 .. 3.0 (every 0.1 s): a 1.0 s hole.
    # The contract in the code: a measured sample is kept when the nearest simulated sample on
    # either side is within max_gap_s (0.2 s), and it lies within the simulated track's span; the
    # kept ones are interpolated linearly, also across the hole.
    ts = np.concatenate([np.arange(11) / 10, 2.0 + np.arange(11) / 10])
    s = track("f1", ts, ts)                          # x = t in the simulation
    tm = np.array([-0.1, 0.55, 1.1, 1.5, 1.85, 3.05])
    m = track("f1", tm, tm - 0.05)                   # measured x = t - 0.05 -> ex = +0.05 where interpolated
    e = track_errors(m, s, max_gap_s=0.2)
    # -0.10: before the simulated track starts (the nearest sample is 0.1 s away, but it is outside) -> out
    #  0.55: between 0.5 and 0.6 -> in, ex = 0.55 - 0.50 = 0.05
    #  1.10: 0.1 s after 1.0 (<= 0.2) -> in, interpolated across the hole: x = 1.0 + (2.0 - 1.0) * 0.1 = 1.1,
    #        ex = 1.1 - 1.05 = 0.05
    #  1.50: 0.5 s from both 1.0 and 2.0 (> 0.2) -> out
    #  1.85: 0.15 s before 2.0 -> in, x = 1.85, ex = 0.05
    #  3.05: after the simulated track ends (0.05 s after its last sample) -> out
    np.testing.assert_allclose(e["t_s"], [0.55, 1.1, 1.85])
    np.testing.assert_allclose(e["ex_m"], 0.05, atol=1e-12)
    # A tighter max_gap_s drops the samples near the hole's edges too (0.1 and 0.15 s from a sample).
    np.testing.assert_allclose(track_errors(m, s, max_gap_s=0.09)["t_s"], [0.55])
    # A hole up to 2 * max_gap_s is interpolated across all the way: 0.3 s hole, sample in its middle.
    s2 = track("f1", [0.0, 0.1, 0.4, 0.5], [0.0, 0.1, 0.4, 0.5])
    e2 = track_errors(track("f1", [0.25], [0.2]), s2, max_gap_s=0.2)
    np.testing.assert_allclose(e2["ex_m"], [0.05], atol=1e-12)  # 0.25 - 0.20


def test_track_errors_fish_without_simulated_track_is_left_out():
    tm = np.array([0.0, 0.1, 0.2])
    m = pd.concat([track("f1", tm, tm), track("f2", tm, tm)], ignore_index=True)
    s = pd.concat([track("f1", tm, tm + 0.02), track("f2", [0.1], [0.1])], ignore_index=True)  # f2: one sample
    e = track_errors(m, s)
    assert e["fish_id"].tolist() == ["f1"] * 3
    np.testing.assert_allclose(e["ex_m"], 0.02, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# belt_residuals
# --------------------------------------------------------------------------------------------------

def errors_frame(fid: str, t, x, ex, yaw=0.0) -> pd.DataFrame:
    t = np.asarray(t, float)
    return pd.DataFrame({"fish_id": fid, "t_s": t, "x_m": np.asarray(x, float), "y_m": 0.0,
                         "yaw_rad": np.broadcast_to(np.asarray(yaw, float), t.shape), "ex_m": np.asarray(ex, float),
                         "ey_m": 0.0, "eyaw_rad": 0.0})


def lone_fish_errors() -> pd.DataFrame:
    # Fish 0.6 m long.  It lies wholly on belt a while 0.35 < x < 1.65 (ends 0.05 inside 0 and 2 m)
    # and on belt b while 2.35 < x < 5.65.
    #   belt a: 6 samples at x = 0.5 .. 1.5, error -0.02 m (one outlier +0.50), heading 0 rad
    #   transfer: x = 1.8 .. 2.2, on neither belt (not counted)
    #   belt b: 6 samples at x = 2.5 .. 3.5, error -0.05 m, heading pi/3 (cos = 0.5)
    t = np.arange(15) * 0.2
    x = np.concatenate([np.linspace(0.5, 1.5, 6), [1.8, 1.9, 2.1], np.linspace(2.5, 3.5, 6)])
    ex = np.array([-0.02, -0.02, 0.50, -0.02, -0.02, -0.02, -0.03, -0.04, -0.05] + [-0.05] * 6)
    yaw = np.array([0.0] * 9 + [math.pi / 3] * 6)
    return errors_frame("f1", t, x, ex, yaw)


def test_belt_residuals_lone_fish_lag_heading_hours():
    e = lone_fish_errors()
    run = make_run(fish_table({"fish_id": "f1", "hours_post_mortem": 12.0}),
                   e[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]])
    r = belt_residuals(run, e, LINE)
    assert_dtypes(r, BELT_RESIDUAL_DTYPES)
    assert r["belt"].tolist() == [0, 1] and r["conveyor_id"].tolist() == ["a", "b"]
    assert r["n_samples"].tolist() == [6, 6]
    np.testing.assert_allclose(r["t_start_s"], [0.0, 1.8])   # samples 0..5 at 0.2 s, 9..14
    np.testing.assert_allclose(r["t_end_s"], [1.0, 2.8])
    # belt a: offset = median(-0.02 x5, +0.50) = -0.02 (the median, so the outlier does not count;
    # a mean would give (5 * -0.02 + 0.5) / 6 = +0.0667); lag since the drop (offset 0) = -0.02.
    # belt b: offset -0.05, lag = -0.05 - (-0.02) = -0.03: the slip across the transfer.
    np.testing.assert_allclose(r["offset_m"], [-0.02, -0.05], atol=1e-12)
    np.testing.assert_allclose(r["lag_m"], [-0.02, -0.03], atol=1e-12)
    np.testing.assert_allclose(r["heading"], [1.0, 0.5], atol=1e-12)  # median cos(yaw): cos 0, cos pi/3
    np.testing.assert_allclose(r["hours_post_mortem"], [12.0, 12.0])  # the fish's own value
    np.testing.assert_allclose(r["length_m"], [0.6, 0.6])
    assert r["crowded"].tolist() == [False, False]
    assert r["crowded"].dtype == bool
    assert len(alone(r)) == 2


def test_belt_residuals_hours_fall_back_to_the_run():
    e = lone_fish_errors()
    run = make_run(fish_table({"fish_id": "f1"}), e[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]], hours=6.0)
    np.testing.assert_allclose(belt_residuals(run, e, LINE)["hours_post_mortem"], [6.0, 6.0])


def test_belt_residuals_needs_five_samples_on_a_belt():
    # Only 4 samples wholly on belt a (x = 0.5 .. 1.4): no row for it, and belt b's lag is then
    # measured from the drop (offset 0): lag = offset = -0.05.
    e = errors_frame("f1", np.arange(10) * 0.2, [0.5, 0.8, 1.1, 1.4, 2.5, 2.7, 2.9, 3.1, 3.3, 3.5],
                     [-0.02] * 4 + [-0.05] * 6)
    run = make_run(fish_table({"fish_id": "f1"}), e[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]])
    r = belt_residuals(run, e, LINE)
    assert r["belt"].tolist() == [1]
    np.testing.assert_allclose(r["lag_m"], [-0.05], atol=1e-12)


def test_belt_residuals_two_fish_close_together_are_crowded():
    # f1 as above; f2 follows 0.3 m behind (less than a fish length, 0.6 m) at the same times,
    # on the same belt: both rows of both fish are crowded.  Moved 1.0 m behind instead: alone.
    e1 = lone_fish_errors()
    t, x = e1["t_s"].to_numpy(), e1["x_m"].to_numpy()
    for gap, crowded in ((0.3, True), (1.0, False)):
        e2 = errors_frame("f2", t, x - gap, e1["ex_m"].to_numpy(), 0.0)
        tracks = pd.concat([e1, e2], ignore_index=True)[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]]
        tracks = tracks.sort_values(["fish_id", "t_s"], kind="stable").reset_index(drop=True)
        run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), tracks)
        r = belt_residuals(run, e1, LINE)
        assert r["crowded"].dtype == bool
        assert r["crowded"].tolist() == [crowded, crowded], gap
        assert len(alone(r)) == (0 if crowded else 2)


def test_belt_residuals_crowding_is_judged_since_the_previous_belt():
    # f2 is beside f1 (0.3 m behind) only while f1 is still on belt a (t <= 1.0 s) and far away
    # afterwards: belt a's row is crowded; belt b's window runs from belt a's last sample (1.0 s)
    # -- so the sample at 1.0 s, still close, counts for belt b too.  At 1.2 s it is already far:
    # with the close samples ending at 0.8 s, belt b's row is alone.
    e1 = lone_fish_errors()
    t, x = e1["t_s"].to_numpy(), e1["x_m"].to_numpy()
    for last_close, crowded_b in ((1.0, True), (0.8, False)):
        x2 = np.where(t <= last_close + 1e-9, x - 0.3, x - 2.0)
        tracks = pd.concat([e1[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]], track("f2", t, x2)], ignore_index=True)
        run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), tracks)
        assert belt_residuals(run, e1, LINE)["crowded"].tolist() == [True, crowded_b], last_close


# --------------------------------------------------------------------------------------------------
# pair_residuals
# --------------------------------------------------------------------------------------------------

def pair_tracks(follower_gap: float, follower_dy: float, leader_speed_after: float, dt: float = 0.1) -> pd.DataFrame:
    # Leader f1 at 0.5 m/s: x = 1.52 + 0.5 t, so x = 1.97 at 0.9 s and 2.02 at 1.0 s: its mid-point
    # crosses the transfer at x = 2 between those samples (tc = 1.0 s); after tc it rides belt b at
    # leader_speed_after: x = 2.02 + v (t - 1).  Follower f2 stays at 0.5 m/s, follower_gap behind.
    t = np.round(np.arange(0.0, 3.0 + 1e-9, dt), 6)
    xa = np.where(t <= 1.0, 1.52 + 0.5 * t, 2.02 + leader_speed_after * (t - 1.0))
    xb = 1.52 - follower_gap + 0.5 * t
    return pd.concat([track("f1", t, xa), track("f2", t, xb, y=follower_dy)], ignore_index=True)


def test_pair_residuals_extra_separation():
    # Measured: leader at 1.0 m/s on belt b.  At tc + 1.5 s = 2.5 s:
    #   leader x = 2.02 + 1.0 * 1.5 = 3.52, follower x = 1.22 + 0.5 * 2.5 = 2.47 -> separation 1.05 m.
    # Simulated (other sample times, 0.05 s): leader at 1.2 m/s -> 2.02 + 1.8 = 3.82, follower 2.47
    #   -> separation 1.35 m.  dsep = 1.35 - 1.05 = +0.30 m.
    # The pair touches at tc: dx = 2.02 - 1.72 = 0.30 < reach = 0.6 - 0.25 * 0.6 = 0.45 and
    # dy = 0 < side = 0.10 + 0.02 = 0.12.
    run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), pair_tracks(0.3, 0.0, 1.0))
    sim = pair_tracks(0.3, 0.0, 1.2, dt=0.05)
    r = pair_residuals(run, sim, LINE)
    assert_dtypes(r, PAIR_RESIDUAL_DTYPES)
    assert len(r) == 1
    row = r.iloc[0]
    assert (row["run_id"], row["leader"], row["follower"], row["conveyor_id"]) == ("r01", "f1", "f2", "b")
    assert row["t_s"] == pytest.approx(1.0)
    assert row["separation_m"] == pytest.approx(1.05)
    assert row["dsep_m"] == pytest.approx(0.30)
    # after_s = 1.0: measured 2.02 + 1.0 - (1.22 + 1.0) = 0.80, simulated 2.02 + 1.2 - 2.22 = 1.00 -> +0.20.
    r1 = pair_residuals(run, sim, LINE, after_s=1.0)
    assert r1["separation_m"].iloc[0] == pytest.approx(0.80)
    assert r1["dsep_m"].iloc[0] == pytest.approx(0.20)


def belt_log(speeds: dict[str, float]) -> pd.DataFrame:
    t = np.arange(0.0, 3.01, 0.5)
    return pd.concat([pd.DataFrame({"t_s": t, "conveyor_id": c, "speed_mps": v, "setpoint_mps": v})
                      for c, v in speeds.items()], ignore_index=True)


def test_pair_residuals_say_how_far_the_pair_would_part_on_its_own_belts():
    # Belts a at 0.5 m/s, b at 1.0 m/s (logged): riding their own belts for 1.5 s the pair parts by 0.75 m.
    run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), pair_tracks(0.3, 0.0, 1.0))
    run.belts = belt_log({"a": 0.5, "b": 1.0})
    r = pair_residuals(run, pair_tracks(0.3, 0.0, 1.2, dt=0.05), LINE)
    assert r["parting_m"].iloc[0] == pytest.approx(0.75)
    # belts about as fast (0.03 m/s apart): no parting to share
    run.belts = belt_log({"a": 0.5, "b": 0.53})
    assert np.isnan(pair_residuals(run, pair_tracks(0.3, 0.0, 1.2, dt=0.05), LINE)["parting_m"].iloc[0])


def test_a_runs_pairs_are_scored_as_one_level_of_how_far_they_part():
    # Four pairs at a transfer where they would part by 0.5 m: extra separations +0.5, +0.5, -0.25, +0.25 m are
    # shares +1, +1, -0.5, +0.5 of it, mean 0.5: the level's square 4 x 0.25 = 1.0 over 4 pairs (pair by pair the
    # squares would sum to 0.5625 m^2). A fifth pair at belts too close in speed is left out.
    pairs = pd.DataFrame({"run_id": "r01", "leader": list("abcde"), "follower": list("vwxyz"), "conveyor_id": "b",
                          "t_s": 1.0, "separation_m": 0.4, "dsep_m": [0.5, 0.5, -0.25, 0.25, 9.0],
                          "parting_m": [0.5, 0.5, 0.5, 0.5, np.nan]})
    rr = RunResiduals("r01", rows=pd.DataFrame(), pairs=pairs, track_rms_m=0.0)
    assert rr.squares("pair_levels") == (pytest.approx(1.0), 4)
    assert rr.squares("pairs") == (pytest.approx(0.25 + 0.25 + 0.0625 + 0.0625 + 81.0), 5)
    # pairs that part, on the whole, as measured score nothing however they scatter
    pairs["dsep_m"] = [0.5, -0.5, 0.25, -0.25, 0.0]
    assert rr.squares("pair_levels") == (pytest.approx(0.0), 4)
    none_to_share = RunResiduals("r02", rows=pd.DataFrame(), pairs=pairs.iloc[4:], track_rms_m=0.0)
    assert none_to_share.squares("pair_levels") == (0.0, 0)


@pytest.mark.parametrize("gap, dy", [(0.5, 0.0),    # 0.5 m behind: dx = 0.5 > reach 0.45, not touching
                                     (0.3, 0.15)])  # beside at dy = 0.15 > side 0.12, not touching
def test_pair_residuals_fish_apart_are_no_pair(gap, dy):
    run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), pair_tracks(gap, dy, 1.0))
    r = pair_residuals(run, pair_tracks(gap, dy, 1.2), LINE)
    assert r.empty
    assert_dtypes(r, PAIR_RESIDUAL_DTYPES)


def test_pair_residuals_simulation_too_short_gives_no_row():
    # The simulated tracks end at 2.0 s, before tc + after_s = 2.5 s: no separation to compare.
    run = make_run(fish_table({"fish_id": "f1"}, {"fish_id": "f2"}), pair_tracks(0.3, 0.0, 1.0))
    sim = pair_tracks(0.3, 0.0, 1.2)
    assert pair_residuals(run, sim[sim["t_s"] <= 2.0], LINE).empty


# --------------------------------------------------------------------------------------------------
# drive_residuals / drive_residuals_averaged
# --------------------------------------------------------------------------------------------------

def drive_check(step_t: float, dt: float = 0.01, n: int = 300, noise: float = 0.0) -> pd.DataFrame:
    # Setpoint 0.5 m/s, stepping to 1.0 m/s at step_t; the model follows the setpoint exactly; the
    # logged speed droops by 1e-4 (m/s)/N under the load: 100 N before the step (-0.01 m/s),
    # 200 N after it (-0.02 m/s), plus an alternating +-noise.
    k = np.arange(n)
    t = k * dt
    sp = np.where(t < step_t - 1e-9, 0.5, 1.0)
    load = np.where(t < step_t - 1e-9, 100.0, 200.0)
    measured = sp - 1e-4 * load + noise * np.where(k % 2 == 0, 1.0, -1.0)
    return pd.DataFrame({"t_s": t, "setpoint_mps": sp, "measured_mps": measured, "model_mps": sp,
                         "load_force_n": load, "load_mass_kg": load / 9.81})


def test_drive_residuals_after_settle():
    # 10 Hz, step at 1.0 s, settle_s 0.45; logged and model speed within 5 % of the setpoint from the start of
    # each stretch (the droop is 2 %): steady for 0.45 <= t < 1.0 (the log's start counts as a change: a drive
    # starting from rest ramps) and t >= 1.45 (1.5 .. 2.9 on this grid); 1.0 .. 1.4 is the ramp, left out.
    c = drive_check(1.0, dt=0.1, n=30)
    r = drive_residuals(c, settle_s=0.45)
    np.testing.assert_allclose(r["t_s"], np.r_[np.arange(5, 10), np.arange(15, 30)] * 0.1)
    # residual = measured - model = -1e-4 * load: -0.01 before the step, -0.02 after it
    np.testing.assert_allclose(r["residual_mps"], np.r_[[-0.01] * 5, [-0.02] * 15], atol=1e-12)
    assert r["residual_mps"].dtype == np.dtype(float)
    # A longer settle keeps fewer samples: settle 0.95 -> nothing before the step, from 1.95 after it (2.0 .. 2.9).
    np.testing.assert_allclose(drive_residuals(c, settle_s=0.95)["t_s"].to_numpy(), np.arange(20, 30) * 0.1)


def test_drive_residuals_wait_until_a_ramp_has_reached_the_setpoint():
    # A drive starting from rest: the logged speed ramps 0 -> 1 m/s over 2 s (the model at once); steady only
    # from when the logged speed is within 5 % of the setpoint (t = 1.9 s) plus settle_s 0.3: t >= 2.2 s.
    t = np.arange(40) * 0.1
    c = pd.DataFrame({"t_s": t, "setpoint_mps": 1.0, "measured_mps": np.minimum(t / 2.0, 1.0), "model_mps": 1.0,
                      "load_force_n": 0.0, "load_mass_kg": 0.0})
    r = drive_residuals(c, settle_s=0.3)
    np.testing.assert_allclose(r["t_s"], t[t >= 2.2 - 1e-9])
    assert (r["residual_mps"] == 0.0).all()


def test_drive_residuals_belt_stopped_is_left_out():
    # Setpoint 0 (|sp| <= 0.05 m/s) is never steady, however long ago it was set.
    c = drive_check(1.0, dt=0.1, n=30).assign(setpoint_mps=0.0, model_mps=0.0)
    assert drive_residuals(c).empty


def test_drive_residuals_averaged_windows():
    # 100 Hz, 3 s, step at 1.3 s, settle 0.495 -> steady for 0.495 <= t < 1.3 and t >= 1.8 (samples 50..129,
    # 180..299). Windows of 0.5 s (50 samples), kept with at least half of them (25):
    #   [0, 0.5)    no samples (the log's start settles like a change)
    #   [0.5, 1.0)  50 samples, t mean 0.745, -0.01, 100
    #   [1.0, 1.5)  30 samples (1.00 .. 1.29), t mean 1.145, -0.01, 100
    #   [1.5, 2.0)  20 samples (1.80 .. 1.99) < 25: left out
    #   [2.0, 2.5)  50 samples, t mean 2.245, -0.02, 200
    #   [2.5, 3.0)  50 samples, t mean 2.745, -0.02, 200
    # The +-3 mm/s alternating noise averages out in each window (even sample counts).
    c = drive_check(1.3, noise=0.003)
    raw = drive_residuals(c, settle_s=0.495)
    assert len(raw) == 80 + 120
    np.testing.assert_allclose(raw["residual_mps"].abs().max(), 0.023, atol=1e-12)  # 0.02 + noise
    a = drive_residuals_averaged(c, window_s=0.5, settle_s=0.495)
    np.testing.assert_allclose(a["t_s"], [0.745, 1.145, 2.245, 2.745], atol=1e-9)
    np.testing.assert_allclose(a["residual_mps"], [-0.01, -0.01, -0.02, -0.02], atol=1e-12)
    np.testing.assert_allclose(a["load_force_n"], [100, 100, 200, 200])
    np.testing.assert_allclose(a["setpoint_mps"], [0.5, 0.5, 1.0, 1.0])
    assert list(a.index) == list(range(4))


# --------------------------------------------------------------------------------------------------
# empty inputs and typed frames
# --------------------------------------------------------------------------------------------------

def test_empty_inputs_give_typed_empty_frames():
    empty_tracks = track("x", [], [])
    e = track_errors(empty_tracks, empty_tracks)
    assert e.empty
    assert_dtypes(e, TRACK_ERROR_DTYPES)
    # measured samples but no simulated track at all: also typed
    assert_dtypes(track_errors(track("f1", [0.0, 0.1], [0.5, 0.6]), empty_tracks), TRACK_ERROR_DTYPES)

    run = make_run(fish_table({"fish_id": "f1"}), empty_tracks)
    b = belt_residuals(run, e, LINE)
    assert b.empty
    assert_dtypes(b, BELT_RESIDUAL_DTYPES)
    assert b["crowded"].dtype == bool
    assert alone(b).empty

    p = pair_residuals(run, empty_tracks, LINE)
    assert p.empty
    assert_dtypes(p, PAIR_RESIDUAL_DTYPES)

    check = pd.DataFrame({c: pd.Series(dtype=float)
                          for c in ("t_s", "setpoint_mps", "measured_mps", "model_mps", "load_force_n")})
    for d in (drive_residuals(check), drive_residuals_averaged(check)):
        assert d.empty
        assert d["residual_mps"].dtype == np.dtype(float)
        assert d["load_force_n"].dtype == np.dtype(float)


def test_concat_keeps_bool_crowded_with_empty_parts():
    # pandas 3 keeps an empty part's dtype in a concat: an untyped empty frame would make 'crowded'
    # object, where ~False == -1.  concat_typed drops empty parts and re-types the result.
    e = lone_fish_errors()
    run = make_run(fish_table({"fish_id": "f1"}), e[["t_s", "fish_id", "x_m", "y_m", "yaw_rad"]])
    rows = belt_residuals(run, e, LINE)
    empty = belt_residuals(run, e.iloc[:0], LINE)
    untyped_empty = pd.DataFrame(columns=list(BELT_RESIDUAL_DTYPES))
    for parts in ([empty, rows], [rows, empty], [untyped_empty, rows], []):
        out = concat_typed(parts, BELT_RESIDUAL_DTYPES)
        assert_dtypes(out, BELT_RESIDUAL_DTYPES)
        assert len(out) == (2 if parts else 0)
        assert len(alone(out)) == len(out)
    assert_dtypes(typed_frame([], DRIVE_RESIDUAL_DTYPES), DRIVE_RESIDUAL_DTYPES)
    # alone() refuses an object 'crowded' column rather than negating it bitwise
    with pytest.raises(TypeError, match="crowded"):
        alone(rows.astype({"crowded": object}))


# --------------------------------------------------------------------------------------------------
# photo-eye passages
# --------------------------------------------------------------------------------------------------

def passing_fish(fid: str, t0: float, yaw: float = 0.0) -> pd.DataFrame:
    # mid-point at x = 4 m (the beam) at t0 + 0.25 s, moving at 1 m/s, sampled at 25 Hz
    t = np.round(np.arange(t0 - 1.0, t0 + 1.5, 0.04), 3)
    return track(fid, t, 4.0 + (t - t0 - 0.25), yaw=yaw)


def test_photoeye_passage_of_a_flickering_fish():
    # A 0.5 m fish at 1 m/s: its passage past the beam lasts 0.5 s (t 10.0 .. 10.5).  The beam is blocked
    # 10.00-10.20 and 10.25-10.50: one passage of two intervals, blocked 0.45 of 0.5 s = 0.9, and the
    # passage's span 0.5 s x 1 m/s / 0.5 m = 1.0.
    fish = fish_table({"fish_id": "f1", "length_m": 0.5})
    pe = pd.DataFrame({"sensor_id": ["pe", "pe"], "t_on_s": [10.0, 10.25], "t_off_s": [10.2, 10.5]})
    p = photoeye_passages(passing_fish("f1", 10.0), pe, fish, LINE)
    assert len(p) == 1
    row = p.iloc[0]
    assert (row["fish_id"], row["sensor_id"], int(row["intervals"])) == ("f1", "pe", 2)
    assert row["blocked"] == pytest.approx(0.9, abs=1e-9)
    assert row["span"] == pytest.approx(1.0, abs=0.02)  # the speed from 25 Hz samples inside the passage


def test_photoeye_passages_leave_out_crowded_and_crosswise_fish():
    # f2 passes 0.2 m behind f1 (both within reach of the beam at f1's middle): not attributable;
    # f3 rides crosswise (yaw 90 deg: its length is not along the line): left out too.
    fish = fish_table({"fish_id": "f1", "length_m": 0.5}, {"fish_id": "f2", "length_m": 0.5},
                      {"fish_id": "f3", "length_m": 0.5})
    tracks = pd.concat([passing_fish("f1", 10.0), passing_fish("f2", 10.2), passing_fish("f3", 20.0, yaw=np.pi / 2)])
    pe = pd.DataFrame({"sensor_id": ["pe", "pe"], "t_on_s": [10.0, 20.2], "t_off_s": [10.7, 20.3]})
    assert photoeye_passages(tracks, pe, fish, LINE).empty


def test_passage_residuals_compare_the_same_fish():
    # Three fish alone; measured: each beam passage unbroken (blocked 1.0); simulated: each flickers, blocked
    # 0.8 of its passage (0.1 s gap in 0.5 s).  The residual is -0.2 for the beam, over the 3 fish.
    fish = fish_table(*({"fish_id": f"f{i}", "length_m": 0.5} for i in range(3)))
    tracks = pd.concat([passing_fish(f"f{i}", 10.0 + 5 * i) for i in range(3)])
    measured = pd.DataFrame({"sensor_id": "pe", "t_on_s": [10.0, 15.0, 20.0], "t_off_s": [10.5, 15.5, 20.5]})
    simulated = pd.DataFrame({"sensor_id": "pe", "t_on_s": [10.0, 10.3, 15.0, 15.3, 20.0, 20.3],
                              "t_off_s": [10.2, 10.5, 15.2, 15.5, 20.2, 20.5]})
    run = Run(id="r01", hours_post_mortem=6.0, notes="", fish=fish, tracks=tracks, photoeyes=measured)
    r = passage_residuals(run, tracks, simulated, LINE)
    assert_dtypes(r, PASSAGE_RESIDUAL_DTYPES)
    assert len(r) == 1 and int(r["n"].iloc[0]) == 3
    assert r["dblocked"].iloc[0] == pytest.approx(-0.2, abs=1e-9)
    assert r["se"].iloc[0] == MIN_PASSAGE_SE  # no spread over the fish on either side: the floor
    # fewer than three fish at a beam in both: no row (a mean of one or two passages is mostly chance)
    assert passage_residuals(run, tracks, simulated.iloc[:4], LINE).empty
