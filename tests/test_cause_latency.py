"""Photo-eye latency as a candidate cause (fishfmu.analysis.causes.latency): the rows it reads
(``observations.edge_rows``), its covariate test (with the stratified shuffle it needs), its fit, and on data nobody
here made: the independent simulator's eyes reporting 30 ms late (named, fitted near it) and on time (not named).

Our own data: runs of this plant whose line has every photo-eye twice at one place, one on time and one reporting
30 ms late (``latency_s``, plant-side): the same fish and tracks, once seen by on-time eyes and once by late ones.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.contract.line import KpiSettings, Line
from plant.contract.measured import Dataset, Run, read_dataset
from plant.sim.simulate import simulate_plant

from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.analysis.causes.latency import MIN_LATENCY_S, delay_edges, fit
from fishfmu.analysis.covariates import Design, covariate_test
from fishfmu.analysis.extension_fit import FitContext
from fishfmu.analysis.fitting import gain_with_ci
from fishfmu.analysis.observations import edge_rows
from fishfmu.analysis.recovery import recovery, truth_terms
from fishfmu.analysis.signatures import judge, significant
from tests.plant_helpers import fish, straight_line

ROOT = Path(__file__).resolve().parents[1]
LATENCY_S = 0.03
EYES_X = (1.0, 2.4, 3.7)
"""One beam in the middle of each belt (x of the beams), 1.5 cm above it."""


def test_a_dependence_only_between_strata_is_no_dependence_when_shuffled_within_them():
    """Two photo-eyes at belts of 0.3 and 1.5 m/s, each with its own constant offset (5 and 25 mm) and noise, nothing
    within an eye following the speed: shuffling the speed among all passages finds the between-eye difference
    (p = 0.001); shuffled within each eye (``strata``) the speed explains as much in every shuffle (p about 1)."""
    rng = np.random.default_rng(3)
    eye = np.repeat(["a", "b"], 40)
    speed = np.where(eye == "a", 0.3, 1.5) + rng.uniform(-0.05, 0.05, 80)
    y = np.where(eye == "a", 0.005, 0.025) + rng.normal(0.0, 0.002, 80)
    run = np.tile([f"r{k}" for k in range(8)], 10)
    plain = Design(y, run, speed[:, None], ["speed"], np.zeros((80, 0)), within=False, sign=+1)
    strat = Design(y, run, speed[:, None], ["speed"], np.zeros((80, 0)), within=False, sign=+1, strata=eye)
    assert covariate_test("x", "y", "speed", plain, "rows", np.random.default_rng(0)).p_value <= 0.002
    assert covariate_test("x", "y", "speed", strat, "rows", np.random.default_rng(0)).p_value > 0.5


@pytest.fixture(scope="module")
def twin_eyes() -> tuple[Dataset, Dataset]:
    """Six runs of five fish of 0.55-0.67 m released one at a time, the belts at speeds that differ from run to run (+-20 %);
    the same runs seen by on-time eyes and by eyes 30 ms late (the plant's ``latency_s``), each as a dataset whose
    line (what its user believes) has on-time eyes."""
    eyes = tuple((f"pe{k}", x, 0.015) for k, x in enumerate(EYES_X))
    line = straight_line(("c1", 0.0, 1.5, 0.0), ("c2", 1.51, 1.5, 0.0), ("c3", 3.02, 1.5, 0.0), photoeyes=eyes)
    twin = line.model_dump()
    twin["photoeyes"] += [{**p, "id": f"late{k}", "latency_s": LATENCY_S} for k, p in enumerate(twin["photoeyes"])]
    twin = Line.model_validate(twin)
    rng = np.random.default_rng(11)
    on_time, late = [], []
    for r in range(6):
        k = 1.0 + rng.uniform(-0.2, 0.2)
        speeds = {"c1": 0.4 * k, "c2": 0.7 * k, "c3": 1.0 * k}
        sim = simulate_plant(twin, [fish(f"f{i}", length_m=0.55 + 0.03 * i, x_m=0.4, t_s=0.05 + 2.5 * i)
                                    for i in range(5)], speeds, 20.0)
        pe = sim.photoeyes
        is_late = pe["sensor_id"].str.startswith("late")
        renamed = pe[is_late].assign(sensor_id=pe.loc[is_late, "sensor_id"].str.replace("late", "pe"))
        on_time.append(Run(f"r{r}", 24.0, "", sim.fish, sim.tracks, pe[~is_late].reset_index(drop=True), sim.belts))
        late.append(Run(f"r{r}", 24.0, "", sim.fish, sim.tracks, renamed.reset_index(drop=True), sim.belts))
    kpi = KpiSettings(outfeed_photoeye="pe2")
    return Dataset("on_time", "", line, kpi, on_time), Dataset("late", "", line, kpi, late)


def test_the_offset_at_the_edges_is_the_way_the_fish_travelled_in_the_latency(twin_eyes):
    """Passage by passage, the late eyes put the fish 30 ms x its speed further past the beam than the on-time ones
    (the same fish, the same tracks): the rows measure the latency, not the fish."""
    on_time, late = (edge_rows(d) for d in twin_eyes)
    both = on_time.merge(late, on=["run_id", "fish_id", "sensor_id"], suffixes=("", "_late"))
    assert len(both) >= 60  # 6 runs x 5 fish x 3 eyes, nearly all alone
    shift_s = (both["offset_m_late"] - both["offset_m"]) / both["speed_mps"]
    assert shift_s.to_numpy() == pytest.approx(LATENCY_S, abs=0.003)
    # on time, where the blocked part of a fish sits about its mid-point: within a few cm, whatever its speed
    assert on_time["offset_m"].abs().max() < 0.05


def test_late_eyes_are_named_and_the_latency_fitted_and_on_time_eyes_are_not(twin_eyes):
    """The late eyes: latency named, its extension gaining on held-out runs, fitted 30 ms (within 5 ms) later than the
    on-time eyes, which are not named.  This plant records a beam's edge at the end of the step it happened in, half
    a step (5 ms) late on average, on time or not: measured, on time 7.7 ms (interval 0.9-12.4), late 36.4 ms
    (31.2-40.8), so the late interval must hold 35 ms."""
    on_time, late = twin_eyes
    cand = CANDIDATES["photoeye_latency"]
    jl, jo = judge(late, np.random.default_rng(0)), judge(on_time, np.random.default_rng(0))
    test = {t.candidate: t for t in jl.tests}["photoeye_latency"]
    assert jl.cause == "photoeye_latency" and significant(test), test
    assert jo.cause == "none", {t.candidate: (t.p_value, t.effect) for t in jo.tests}
    f = fit(cand, FitContext(late, None, None, None, np.random.default_rng(1), print))
    f0 = fit(cand, FitContext(on_time, None, None, None, np.random.default_rng(1), print))
    assert f.values["latency_s"] - f0.values["latency_s"] == pytest.approx(LATENCY_S, abs=0.005)
    assert f.ci95["latency_s"][0] <= LATENCY_S + 0.5 * 0.01 <= f.ci95["latency_s"][1]
    assert f.confirmed, (f.heldout_gain, f.heldout_gain_ci95)
    assert f0.values["latency_s"] < MIN_LATENCY_S
    assert cand.terms(f.values, None) == {"latency_s": f.values["latency_s"]}
    # a line that says its eyes are 30 ms late explains them: nothing left to name
    told = late.line.model_dump()
    told["photoeyes"] = [{**p, "latency_s": LATENCY_S} for p in told["photoeyes"]]
    told = replace(late, line=Line.model_validate(told))
    test = CANDIDATES["photoeye_latency"].test({"edges": edge_rows(told)}, np.random.default_rng(0))
    assert test.judged and not significant(test) and abs(test.slope) < MIN_LATENCY_S, test


def test_a_gain_with_no_error_to_remove_has_no_interval():
    """Runs whose drives log their setpoint exactly (this plant's belts.csv, no drive FMU) leave the droop test no
    error to remove: its held-out gain is 0 with no interval, not a crash of every test after it."""
    gain, ci = gain_with_ci(np.zeros(4), np.zeros(4), np.random.default_rng(0))
    assert gain == 0.0 and np.isnan(ci).all()


def test_the_extension_delays_a_re_simulations_edges_and_nothing_else():
    """Applied to a re-simulated run's photoeyes table: both edges 30 ms later, the blocked time the same; the other
    candidates leave the table as it was."""
    table = pd.DataFrame({"sensor_id": ["pe", "pe"], "t_on_s": [1.0, 2.5], "t_off_s": [1.6, 3.0]})
    late = CANDIDATES["photoeye_latency"].simulated_edges(table, LATENCY_S)
    assert late["t_on_s"].tolist() == pytest.approx([1.03, 2.53]) and late["t_off_s"].tolist() == pytest.approx(
        [1.63, 3.03])
    assert (late["t_off_s"] - late["t_on_s"]).tolist() == pytest.approx([0.6, 0.5])
    assert delay_edges(table, 0.0).equals(table)
    assert CANDIDATES["mucus_friction"].simulated_edges(table, -0.2) is table


# ------------------------------------------------------------------------------------- the independent simulator
LINESIM = ROOT.parent / "shared" / "linesim"
RECIPE = ["--seed", "21", "--runs", "6", "--design", "campaign", "--jobs", "1"]
"""Six runs of eighteen fish, half released one at a time and half in batches (about 85 s of wall, 47 s of a core
each to make)."""
CASES = {"late": ["--effect", "photoeye_latency", "--pe-latency-s", str(LATENCY_S)], "on_time": ["--effect", "none"]}


def generated(name: str) -> Path:
    """The dataset of this case, made once by the independent simulator (cached by the recipe and its sources, as
    ``tests/test_diagnose_linesim.py`` does)."""
    python = os.environ.get("FISHFMU_LINESIM_PYTHON")
    if not (python and Path(python).exists() and LINESIM.is_dir()):
        why = "no independent simulator: set FISHFMU_LINESIM_PYTHON (.ci/run makes one)"
        if os.environ.get("CI") == "true":
            pytest.fail(why)
        pytest.skip(why)
    key = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(LINESIM.rglob("*.py"))))
    key.update(json.dumps([RECIPE, CASES]).encode())
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "fishfmu" / "linesim-latency" / \
        key.hexdigest()[:16]
    if not (cache / f"{name}.truth.json").exists():
        subprocess.run([python, str(LINESIM / "gen.py"), *CASES[name], *RECIPE, "--out", str(cache / name)],
                       check=True, capture_output=True, timeout=800)
    return cache / name


@pytest.mark.timeout(900)
def test_independent_eyes_30_ms_late_are_named_with_the_latency_near_it():
    """The independent simulator's eyes report each edge 30 ms late plus a jitter of up to 10 ms (5 ms on average):
    latency is named, nothing else is, and the fitted latency's interval holds the 35 ms the edges are late by."""
    path = generated("late")
    truth = json.loads(path.with_name("late.truth.json").read_text())["magnitude"]
    late_by = truth["pe_latency_s"] + 0.5 * truth["pe_jitter_s"]
    dataset = read_dataset(path)
    j = judge(dataset, np.random.default_rng(0))
    assert j.cause == "photoeye_latency"
    assert [t.candidate for t in j.tests if significant(t)] == ["photoeye_latency"]
    f = fit(CANDIDATES["photoeye_latency"], FitContext(dataset, None, None, None, np.random.default_rng(1), print))
    lo, hi = f.ci95["latency_s"]
    assert lo <= late_by <= hi and abs(f.values["latency_s"] - late_by) < 0.015, (f.values, f.ci95)
    assert f.confirmed
    # the benchmark's recovery: the truth in the candidate's terms (latency and half the jitter), within x1.5
    truth = truth_terms("photoeye_latency", {"pe_latency_s": 0.03, "pe_jitter_s": 0.01}, dataset)
    assert truth == {"latency_s": pytest.approx(0.035)}
    assert recovery("photoeye_latency", CANDIDATES["photoeye_latency"].terms(f.values, None), truth)["within"]


@pytest.mark.timeout(900)
def test_independent_eyes_on_time_are_not_named():
    """The same seed without the effect (the same fish and tracks), and the dev dataset without an effect: the
    latency's test names nothing."""
    j = judge(read_dataset(generated("on_time")), np.random.default_rng(0))
    assert j.cause == "none", {t.candidate: t.p_value for t in j.tests}
    dev_none = ROOT.parent / "shared" / "data" / "dev" / "dev_none"
    if dev_none.is_dir():
        t = CANDIDATES["photoeye_latency"].test({"edges": edge_rows(read_dataset(dev_none))}, np.random.default_rng(0))
        assert t.judged and not significant(t), t
