"""Singulation KPIs (contracts/kpis.md) and the outfeed passages they rest on."""

from __future__ import annotations

import json
import math
import time
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from plant.errors import InputError
from plant.contract.kpis import compute_kpis, kpis_from_passages, paper_rounded, round_half_up, singulation_table
from plant.contract.line import KpiSettings, Line
from plant.contract.measured import PHOTOEYES, TRACKS, Run, empty_table
from plant.contract.passages import arrival_times, blocked_periods, passages

V_MPS = 1.0


def speed(v_mps: float = V_MPS):
    return lambda t: np.full(np.shape(t), v_mps)


def table(*intervals: tuple[float, float], source: str | None = None) -> pd.DataFrame:
    df = pd.DataFrame(intervals, columns=["t_start_s", "t_end_s"])
    return df if source is None else df.assign(source=source)


# ----------------------------------------------------------------------------- the paper's Table IV
def test_paper_table_iv_real_column() -> None:
    # 10 fish alone (0.5 s each, 1.5 s apart at 1 m/s), then 4 overlapping pairs; last clears at 45 s
    alone = [(1.0 + 2 * k, 1.5 + 2 * k) for k in range(10)]
    pairs = [iv for t in (25.0, 30.0, 35.0, 44.2) for iv in ((t, t + 0.5), (t + 0.3, t + 0.8))]
    k = kpis_from_passages(table(*alone, *pairs), n_fish=18, first_drop_t_s=0.0, belt_speed_fn=speed(),
                           min_gap_m=0.05)
    assert k["throughput_time_s"] == pytest.approx(45.0)
    assert k["singulated"] == 10 and k["lost"] == 0
    assert k["doubles_out"] == 8                               # the four pairs reach the outfeed together
    assert k["fpm_in"] == pytest.approx(60 * 18 / 45)          # 24.0
    assert k["singulation_rate"] == pytest.approx(10 / 18)    # 0.5556
    assert k["fpm_out"] == pytest.approx(60 * 10 / 45)        # 13.33
    assert paper_rounded(k) == {"fish_in": 18, "throughput_time_s": 45, "fpm_in": 24, "singulated": 10,
                                "singulation_rate_pct": 56, "fpm_out": 13}


def test_paper_table_iv_simulation_column() -> None:
    # 12 fish alone (0.2 s, 0.1 s = 0.1 m apart), 3 side by side, 4 pairs touching end to start; last clears at 8 s
    alone = [(0.1 + 0.3 * k, 0.3 + 0.3 * k) for k in range(12)]
    side_by_side = [(4.0, 4.2)] * 3
    touching = [iv for t in (4.5, 5.3, 6.1, 7.6) for iv in ((t, t + 0.2), (t + 0.2, t + 0.4))]
    k = kpis_from_passages(table(*alone, *side_by_side, *touching), n_fish=23, first_drop_t_s=0.0,
                           belt_speed_fn=speed(), min_gap_m=0.05)
    assert k["singulated"] == 12 and k["throughput_time_s"] == pytest.approx(8.0)
    assert k["doubles_out"] == 11 and k["lost"] == 0           # 3 side by side and 4 touching pairs
    assert k["fpm_in"] == pytest.approx(172.5)                # the paper printed 173: rounded half up
    assert paper_rounded(k) == {"fish_in": 23, "throughput_time_s": 8, "fpm_in": 173, "singulated": 12,
                                "singulation_rate_pct": 52, "fpm_out": 90}


def test_round_half_up_rounds_halves_up_unlike_python_round() -> None:
    assert round_half_up(172.5) == 173 and round(172.5) == 172
    assert round_half_up(55.55, 1) == 55.6 and round_half_up(-2.5) == -3


# ------------------------------------------------------------------------------- singulation rules
def test_touching_fish_are_not_singulated() -> None:
    t = singulation_table(table((1.0, 2.0), (2.0, 3.0), (10.0, 11.0)), speed(), 0.05)
    assert t["singulated"].tolist() == [False, False, True]
    assert t["gap_before_m"].tolist()[1:] == [0.0, 7.0]


def test_overlapping_fish_are_not_singulated_even_with_zero_min_gap() -> None:
    t = singulation_table(table((1.0, 2.0), (1.5, 2.5)), speed(), 0.0)
    assert t["singulated"].tolist() == [False, False]
    assert t["gap_before_m"].iloc[1] == pytest.approx(-0.5)


def test_a_fish_inside_a_longer_passage_overlaps_it() -> None:
    # the third fish starts after the second ends, but the first (long) one is still in the beam
    t = singulation_table(table((1.0, 3.0), (1.2, 1.5), (2.0, 2.5), (5.0, 5.5)), speed(), 0.05)
    assert t["singulated"].tolist() == [False, False, False, True]
    assert t["gap_before_m"].iloc[3] == pytest.approx(2.0)  # from 3.0, the latest end so far


def test_gap_just_under_min_gap_is_not_singulated_just_over_is() -> None:
    v = 1.5  # m/s: 0.048 m of belt pass in 0.032 s, 0.052 m in 0.03467 s
    under = singulation_table(table((1.0, 1.5), (1.5 + 0.048 / v, 2.0)), speed(v), 0.05)
    assert under["gap_before_m"].iloc[1] == pytest.approx(0.048)
    assert under["singulated"].tolist() == [False, False]
    over = singulation_table(table((1.0, 1.5), (1.5 + 0.052 / v, 2.0)), speed(v), 0.05)
    assert over["gap_before_m"].iloc[1] == pytest.approx(0.052)
    assert over["singulated"].tolist() == [True, True]


def test_gap_uses_the_belt_speed_at_that_time() -> None:
    # belt at 1 m/s until 5 s, 3 m/s after; a 0.04 s clear time is 0.04 m early and 0.12 m late
    def v(t):
        return np.where(np.asarray(t) < 5.0, 1.0, 3.0)
    t = singulation_table(table((1.0, 1.5), (1.54, 2.0), (6.0, 6.5), (6.54, 7.0)), v, 0.05)
    assert t["gap_before_m"].tolist()[1:] == pytest.approx([0.04, 4.0, 0.12])  # 4 s clear, centred at 4 s: 1 m/s
    assert t["singulated"].tolist() == [False, False, True, True]


def test_first_and_last_fish_need_only_one_gap_and_a_lone_fish_is_singulated() -> None:
    k = kpis_from_passages(table((1.0, 2.0)), n_fish=1, first_drop_t_s=0.5, belt_speed_fn=speed(), min_gap_m=0.05)
    assert k["singulated"] == 1 and k["singulation_rate"] == 1.0 and k["throughput_time_s"] == 1.5
    assert k["gap_min_m"] is None and k["gap_median_m"] is None and k["gap_p10_m"] is None
    json.dumps(k)


def test_a_lost_fish_counts_in_but_never_out() -> None:
    k = kpis_from_passages(table((10.0, 10.5), (12.0, 12.5)), n_fish=3, first_drop_t_s=0.0, belt_speed_fn=speed(),
                           min_gap_m=0.05)
    assert k["lost"] == 1 and k["singulated"] == 2
    assert k["singulation_rate"] == pytest.approx(2 / 3)
    assert k["throughput_time_s"] == 12.5 and k["fpm_in"] == pytest.approx(60 * 3 / 12.5)


def test_no_passage_at_all_gives_undefined_rates_not_errors() -> None:
    k = kpis_from_passages(table(), n_fish=2, first_drop_t_s=0.0, belt_speed_fn=speed(), min_gap_m=0.05)
    assert k["lost"] == 2 and k["singulated"] == 0 and k["singulation_rate"] == 0.0
    assert k["throughput_time_s"] is None and k["fpm_in"] is None and k["fpm_out"] is None
    assert k["method"] == "none"
    json.dumps(k)


def test_gap_statistics_over_consecutive_passages() -> None:
    # gaps 0.1, 0.2, ..., 1.0 m (at 1 m/s), and one overlap of -0.3 m
    starts = np.cumsum([0.0] + [0.5 + g for g in np.arange(1, 11) / 10])
    p = table(*[(s, s + 0.5) for s in starts], (starts[-1] + 0.2, starts[-1] + 0.6))
    k = kpis_from_passages(p, n_fish=12, first_drop_t_s=0.0, belt_speed_fn=speed(), min_gap_m=0.05)
    gaps = [-0.3] + list(np.arange(1, 11) / 10)
    assert k["gap_min_m"] == pytest.approx(-0.3)
    assert k["gap_median_m"] == pytest.approx(np.median(gaps))  # 0.5
    assert k["gap_p10_m"] == pytest.approx(0.1)                   # 11 gaps: p10 at index 1.0 -> 0.1
    assert k["singulated"] == 10                                 # 12 passages, the last two overlap


# ------------------------------------------------------------------- passages from tracks and beams
LINE = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": 0.0},
    {"id": "c2", "x_start_m": 2.0, "length_m": 2.0, "width_m": 0.5, "z_top_m": -0.02}],
    "photoeyes": [{"id": "pe_in", "x_m": 1.0, "z_m": 0.015}, {"id": "pe_out", "x_m": 3.0, "z_m": -0.005}]})
KPI = KpiSettings(outfeed_photoeye="pe_out", min_gap_m=0.05)
X_BEAM = 3.0


def fish_frame(lengths_m, heights_m=None, drop_t_s=None) -> pd.DataFrame:
    n = len(lengths_m)
    return pd.DataFrame({"fish_id": [f"f{i + 1}" for i in range(n)], "length_m": lengths_m, "weight_kg": 2.0,
                         "height_m": heights_m if heights_m is not None else [0.15] * n, "width_m": 0.07,
                         "hours_post_mortem": 6.0, "drop_t_s": drop_t_s if drop_t_s is not None else [0.0] * n,
                         "drop_x_m": 0.5, "drop_y_m": 0.0, "drop_yaw_rad": 0.0, "drop_z_m": 0.05})


def moving_track(fish_id: str, t_s: np.ndarray, x0_m: float, v_mps: float, yaw_rad: float = 0.0,
                 y_m: float = 0.0) -> pd.DataFrame:
    """A fish whose mid-point moves at constant speed: x = x0 + v t."""
    return pd.DataFrame({"t_s": t_s, "fish_id": fish_id, "x_m": x0_m + v_mps * t_s, "y_m": y_m, "yaw_rad": yaw_rad})


def belts(v_mps: float = V_MPS, t_end_s: float = 30.0) -> pd.DataFrame:
    t = np.arange(0.0, t_end_s, 0.01)
    return pd.DataFrame({"t_s": np.repeat(t, 2), "conveyor_id": np.tile(["c1", "c2"], len(t)),
                         "setpoint_mps": v_mps, "speed_mps": v_mps})


def run_of(fish, tracks=None, photoeyes=None, v_mps: float = V_MPS) -> Run:
    return Run("t", 6.0, "", fish, tracks if tracks is not None else empty_table(TRACKS),
               photoeyes if photoeyes is not None else empty_table(PHOTOEYES), belts(v_mps))


T25 = np.arange(0.0, 10.0, 0.04)  # 25 Hz


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0, 180.0, -90.0])
def test_passage_from_a_fish_at_constant_speed(yaw_deg: float) -> None:
    L, H, v, x0 = 0.6, 0.16, 1.2, 0.4
    ext = L / 2 if yaw_deg % 180 == 0 else H / 2  # along its heading: half its length; across: half its height
    run = run_of(fish_frame([L], [H]), moving_track("f1", T25, x0, v, math.radians(yaw_deg)))
    p = passages(run, LINE, KPI)
    assert p["t_start_s"].iloc[0] == pytest.approx((X_BEAM - ext - x0) / v)  # front reaches the beam
    assert p["t_end_s"].iloc[0] == pytest.approx((X_BEAM + ext - x0) / v)    # rear leaves it
    assert p["source"].iloc[0] == "tracks"


def test_passage_at_45_degrees_uses_length_and_height() -> None:
    L, H, v, x0 = 0.6, 0.16, 1.0, 0.4
    ext = (L / 2 + H / 2) * math.sqrt(0.5)
    run = run_of(fish_frame([L], [H]), moving_track("f1", T25, x0, v, math.radians(45)))
    p = passages(run, LINE, KPI)
    assert p[["t_start_s", "t_end_s"]].iloc[0].tolist() == pytest.approx([X_BEAM - ext - x0, X_BEAM + ext - x0])


def test_passage_with_irregular_samples_and_missing_rows() -> None:
    L, v, x0 = 0.6, 1.2, 0.4
    rng = np.random.default_rng(3)
    t = np.sort(T25 + rng.uniform(-0.01, 0.01, len(T25)))
    keep = rng.random(len(t)) > 0.3  # about a third of the rows lost, gaps of up to a few samples
    keep[(t > 1.82) & (t < 2.02)] = False  # and a 0.2 s hole where the front crosses (at 1.917 s)
    t = t[keep]
    assert np.diff(t).max() < 0.5
    run = run_of(fish_frame([L]), moving_track("f1", t, x0, v))
    p = passages(run, LINE, KPI)
    assert p[["t_start_s", "t_end_s"]].iloc[0].tolist() == pytest.approx([(X_BEAM - L / 2 - x0) / v,
                                                                          (X_BEAM + L / 2 - x0) / v])
    assert p["source"].iloc[0] == "tracks"


def test_a_long_tracking_gap_at_the_beam_is_not_trusted() -> None:
    L, v, x0 = 0.6, 1.0, 0.4   # front reaches the beam at 2.3 s, rear leaves at 2.9 s
    t = T25[(T25 < 1.0) | (T25 > 3.5)]  # tracking lost for 2.5 s across the whole passage
    fish = fish_frame([L])
    # without a photo-eye: interpolated across the gap, and flagged
    p = passages(run_of(fish, moving_track("f1", t, x0, v)), LINE, KPI)
    assert p["source"].iloc[0] == "tracks+estimate"
    # with the beam's interval: the passage is that interval
    pe = pd.DataFrame({"sensor_id": ["pe_out"], "t_on_s": [2.31], "t_off_s": [2.88]})
    p = passages(run_of(fish, moving_track("f1", t, x0, v), pe), LINE, KPI)
    assert p[["t_start_s", "t_end_s", "source"]].iloc[0].tolist() == [2.31, 2.88, "tracks+photoeye"]


def test_track_ending_inside_the_beam_is_completed_by_the_beam_or_the_belt() -> None:
    L, v, x0 = 0.6, 1.0, 0.4   # front at the beam at 2.3 s; the track stops at 2.5 s
    t = T25[T25 < 2.5]
    fish = fish_frame([L])
    p = passages(run_of(fish, moving_track("f1", t, x0, v)), LINE, KPI)
    assert p["t_end_s"].iloc[0] == pytest.approx(2.3 + L / v)  # its own length at belt speed
    pe = pd.DataFrame({"sensor_id": ["pe_out"], "t_on_s": [2.31], "t_off_s": [2.95]})
    p = passages(run_of(fish, moving_track("f1", t, x0, v), pe), LINE, KPI)
    assert p["t_start_s"].iloc[0] == pytest.approx(2.31) and p["t_end_s"].iloc[0] == 2.95


def test_a_lone_fish_is_snapped_to_its_blocked_interval_and_flicker_is_merged() -> None:
    L, v, x0 = 0.6, 1.0, 0.4   # tracks: 2.3 .. 2.9 s
    # the beam: 2.32-2.40, clear for 0.01 s (0.01 m < min_gap: flicker), 2.41-2.87
    pe = pd.DataFrame({"sensor_id": ["pe_out", "pe_out"], "t_on_s": [2.32, 2.41], "t_off_s": [2.40, 2.87]})
    p = passages(run_of(fish_frame([L]), moving_track("f1", T25, x0, v), pe), LINE, KPI)
    assert p[["t_start_s", "t_end_s", "source"]].iloc[0].tolist() == [2.32, 2.87, "tracks+photoeye"]
    assert blocked_periods(pe, "pe_out", speed(), 0.05).to_numpy().tolist() == [[2.32, 2.87]]
    assert len(blocked_periods(pe, "pe_out", speed(), 0.005)) == 2


def test_fish_sharing_a_blocked_interval_keep_their_inner_times() -> None:
    L, v = 0.6, 1.0
    # f1: 2.3 .. 2.9 s, f2 0.4 m behind: 2.7 .. 3.3 s; the beam is blocked 2.32 .. 3.27
    tracks = pd.concat([moving_track("f1", T25, 0.4, v), moving_track("f2", T25, 0.0, v)])
    pe = pd.DataFrame({"sensor_id": ["pe_out"], "t_on_s": [2.32], "t_off_s": [3.27]})
    p = passages(run_of(fish_frame([L, L]), tracks, pe), LINE, KPI)
    assert p["fish_id"].tolist() == ["f1", "f2"]
    assert p["t_start_s"].tolist() == pytest.approx([2.32, 2.7])
    assert p["t_end_s"].tolist() == pytest.approx([2.9, 3.27])


def test_side_by_side_fish_are_not_singulated() -> None:
    L, v = 0.6, 1.0
    tracks = pd.concat([moving_track("f1", T25, 0.4, v, y_m=0.1), moving_track("f2", T25, 0.4, v, y_m=-0.1)])
    k = compute_kpis(run_of(fish_frame([L, L]), tracks), LINE, KPI)
    assert k["singulated"] == 0 and k["lost"] == 0 and k["gap_min_m"] == pytest.approx(-L)


def test_photoeye_only_run_estimates_fish_from_blocked_length() -> None:
    # no tracks; belt 1.5 m/s; fish 0.6 m: 0.4 s blocked is one fish, 0.8 s is two
    v = 1.5
    pe = pd.DataFrame({"sensor_id": ["pe_in", "pe_out", "pe_out"], "t_on_s": [1.0, 5.0, 8.0],
                       "t_off_s": [1.4, 5.4, 8.8]})
    k = compute_kpis(run_of(fish_frame([0.6, 0.58, 0.62]), photoeyes=pe, v_mps=v), LINE, KPI)
    assert k["method"] == "photoeyes" and k["estimated_fish"] == 3 and k["passage_sources"] == {"photoeye": 3}
    assert k["singulated"] == 1 and k["lost"] == 0
    assert k["gap_min_m"] == pytest.approx(-0.8 * v)  # the two in one interval overlap fully
    json.dumps(k)


def test_beam_finds_a_fish_the_tracks_lost_and_says_so() -> None:
    L, v = 0.6, 1.0
    tracks = pd.concat([moving_track("f1", T25, 0.4, v), moving_track("f2", T25[T25 < 1.0], -2.0, v)])
    pe = pd.DataFrame({"sensor_id": ["pe_out", "pe_out"], "t_on_s": [2.3, 4.7], "t_off_s": [2.9, 5.3]})
    k = compute_kpis(run_of(fish_frame([L, L]), tracks, pe), LINE, KPI)
    assert k["method"] == "mixed" and k["estimated_fish"] == 1 and k["lost"] == 0 and k["singulated"] == 2
    assert k["throughput_time_s"] == pytest.approx(5.3)
    # a blocked pulse much shorter than any fish is not a fish: f2 is then lost
    pe.loc[1, "t_off_s"] = 4.72
    k = compute_kpis(run_of(fish_frame([L, L]), tracks, pe), LINE, KPI)
    assert k["method"] == "tracks" and k["lost"] == 1


def test_beam_never_adds_more_fish_than_are_missing() -> None:
    tracks = moving_track("f1", T25, 0.4, 1.0)
    pe = pd.DataFrame({"sensor_id": ["pe_out"] * 3, "t_on_s": [2.3, 4.0, 6.0], "t_off_s": [2.9, 5.2, 6.6]})
    k = compute_kpis(run_of(fish_frame([0.6, 0.6]), tracks, pe), LINE, KPI)
    assert k["estimated_fish"] == 1 and k["lost"] == 0 and k["fish_in"] == 2


def test_arrival_times_at_every_photoeye() -> None:
    L, v, x0 = 0.6, 1.2, 0.4
    t = T25[(T25 < 0.3) | (T25 > 1.2)]  # f2 is not tracked for 0.9 s
    tracks = pd.concat([moving_track("f1", T25, x0, v), moving_track("f2", t, x0 - 0.3, v),
                        moving_track("f3", T25[T25 < 1.0], 0.0, 0.5)])
    a = arrival_times(run_of(fish_frame([L, L, L]), tracks), LINE).set_index(["fish_id", "sensor_id"])
    assert a.loc[("f1", "pe_in"), "t_s"] == pytest.approx((1.0 - L / 2 - x0) / v)
    assert a.loc[("f1", "pe_out"), "t_s"] == pytest.approx((3.0 - L / 2 - x0) / v)
    # f2's front reaches pe_in at (1.0 - 0.3 - 0.1) / 1.2 = 0.5 s, inside its 0.9 s tracking hole
    assert a.loc[("f2", "pe_in"), "status"] == "gap" and np.isnan(a.loc[("f2", "pe_in"), "t_s"])
    assert a.loc[("f2", "pe_out"), "t_s"] == pytest.approx((3.0 - L / 2 - x0 + 0.3) / v)
    assert a.loc[("f3", "pe_out"), "status"] == "not_reached"
    k = compute_kpis(run_of(fish_frame([L, L, L]), tracks), LINE, KPI)
    assert k["arrival_t_s"]["pe_in"]["f2"] is None
    assert k["arrival_t_s"]["pe_out"]["f1"] == pytest.approx((3.0 - L / 2 - x0) / v)
    assert k["lost"] == 1


def test_a_100_fish_60_s_run_takes_well_under_a_second() -> None:
    n, v = 100, 1.0
    t = np.arange(0.0, 60.0, 0.04)
    rng = np.random.default_rng(0)
    starts = np.sort(rng.uniform(0.0, 50.0, n))
    tracks = pd.concat([moving_track(f"f{i + 1}", t[t >= s], -s * v + 0.5, v, rng.normal(0, 0.1))
                        for i, s in enumerate(starts)])
    tracks = tracks.sort_values("t_s", kind="stable")  # every fish tracked to the end: ~90 000 rows
    fish = fish_frame(list(rng.uniform(0.5, 0.7, n)), drop_t_s=list(starts))
    pe = pd.DataFrame({"sensor_id": "pe_out", "t_on_s": starts + 2.0, "t_off_s": starts + 2.6})
    run = Run("big", 6.0, "", fish, tracks, pe, belts(v, 61.0))
    t0 = time.perf_counter()
    k = compute_kpis(run, LINE, KPI)
    elapsed = time.perf_counter() - t0
    assert k["fish_in"] == 100 and k["lost"] == 0 and len(tracks) > 50_000
    assert elapsed < 0.5, f"{elapsed:.3f} s"


def test_a_simulated_run_needs_only_the_four_tables() -> None:
    sim = SimpleNamespace(fish=fish_frame([0.6]), tracks=moving_track("f1", T25, 0.4, 1.0),
                          photoeyes=empty_table(PHOTOEYES), belts=belts())
    k = compute_kpis(sim, LINE, KPI)
    assert k["singulated"] == 1 and k["throughput_time_s"] == pytest.approx(2.9)


def test_missing_outfeed_belt_log_is_an_input_error_naming_the_file() -> None:
    run = run_of(fish_frame([0.6]), moving_track("f1", T25, 0.4, 1.0))
    run.belts = run.belts[run.belts["conveyor_id"] == "c1"]
    with pytest.raises(InputError, match=r"belts\.csv: no samples for conveyor 'c2'"):
        compute_kpis(run, LINE, KPI)
