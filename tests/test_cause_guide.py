"""The guide wear candidate (:mod:`fishfmu.analysis.causes.guide`): its rows read from tracks and belt logs against
values worked out by hand, its covariate test on rows made by hand (named with the effect, not without it, not for a
slippery stretch that holds back every fish on it), the strata shuffle it is judged by, its fit (on stand-in
simulations) and its terms."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from plant.contract.line import KpiSettings
from plant.contract.measured import Dataset, Run
from plant.sim.params import PlantParams

from fishfmu.analysis.candidate import Terms
from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.analysis.causes import guide
from fishfmu.analysis.covariates import Design, _shuffled
from fishfmu.analysis.observations import STRETCH_M, guide_rows
from fishfmu.analysis.signatures import significant
from tests.plant_helpers import straight_line

LINE_M = 6.0


def hand_rows(wear_mps: float, zone_mps: float = 0.0, seed: int = 1, runs: int = 6) -> pd.DataFrame:
    """Rows of six runs: per run 40 fish clear of the guides and 8 touching one on every stretch of a 6 m line, each
    stretch with its own level of slip (noise 8 mm/s), fish at a guide 5 mm/s more; with ``wear_mps`` the touching
    fish's slip grows by that much from the first stretch to the last; with ``zone_mps`` every fish on the last
    metre slips that much more (a slippery zone)."""
    rng = np.random.default_rng(seed)
    x = (np.arange(int(LINE_M / STRETCH_M)) + 0.5) * STRETCH_M
    level = rng.normal(0.0, 0.005, len(x))
    rows = []
    for r in range(runs):
        for touching, n in ((0.0, 40), (1.0, 8)):
            for _ in range(n):
                k = int(rng.integers(len(x)))
                slip = level[k] + (x[k] > LINE_M - 1.0) * zone_mps + rng.normal(0.0, 0.008)
                slip += touching * (0.005 + wear_mps * (x[k] - x[0]) / (x[-1] - x[0]))
                rows.append({"run_id": f"r{r}", "conveyor_id": f"c{int(x[k] // 1.5) + 1}", "x_m": x[k],
                             "slip_mps": slip, "touching": touching})
    return pd.DataFrame(rows)


def judged(rows: pd.DataFrame):
    return guide.test({"guides": rows}, np.random.default_rng(0))


def test_slip_growing_along_the_line_at_the_guides_is_named():
    t = judged(hand_rows(wear_mps=0.02))
    assert significant(t), t
    assert t.slope == pytest.approx(0.02, abs=0.006)  # the growth put in, from the first stretch to the last


def test_guide_contact_that_holds_fish_back_the_same_everywhere_is_not_named():
    t = judged(hand_rows(wear_mps=0.0))
    assert t.judged and not significant(t), t


def test_a_slippery_stretch_holding_back_every_fish_on_it_is_not_guide_wear():
    """The scan's alternative at the same place: a zone of belt that slows all fish, touching a guide or not."""
    t = judged(hand_rows(wear_mps=0.0, zone_mps=0.03))
    assert t.judged and not significant(t), t


def test_a_growth_too_small_to_matter_is_not_named():
    t = judged(hand_rows(wear_mps=0.5 * guide.MIN_SLIP_MPS, runs=40))
    assert t.p_value <= 0.02 and not significant(t), t  # clear by chance, but under the smallest effect worth naming


def test_too_few_runs_with_guide_contact_cannot_be_judged():
    rows = hand_rows(wear_mps=0.02)
    rows = rows[(rows["touching"] == 0.0) | rows["run_id"].isin(["r0", "r1"])]
    t = judged(rows)
    assert not t.judged and "only 2 runs" in t.note


def test_the_strata_shuffle_exchanges_the_covariate_only_within_each_stratum():
    shapes = np.arange(10.0)[:, None]
    strata = np.array([0, 1, 0, 1, 0, 1, 0, 1, 2, 2])
    d = Design(np.zeros(10), np.zeros(10), shapes, ["x"], np.zeros((10, 0)), within=False, strata=strata)
    seen = set()
    for _ in range(50):
        out = _shuffled(d, np.random.default_rng(len(seen)), "strata")[:, 0]
        for s in (0, 1, 2):
            assert sorted(out[strata == s]) == sorted(shapes[strata == s, 0])
        seen.add(tuple(out))
    assert len(seen) > 10  # it does shuffle
    with pytest.raises(ValueError):
        _shuffled(Design(np.zeros(2), np.zeros(2), shapes[:2], ["x"], np.zeros((2, 0)), within=False),
                  np.random.default_rng(0), "strata")


def one_run_dataset(y_m: float, fish_mps: float, belt_mps: float = 0.5) -> Dataset:
    """One 0.6 m fish (height 0.16 m) riding straight along a 3 m belt at ``fish_mps`` at ``y_m``, tracked at 25 Hz
    without noise, the belt logged at ``belt_mps``."""
    line = straight_line(("c1", 0.0, 3.0, 0.0))
    t = np.arange(0.0, 6.0, 0.04)
    fish = pd.DataFrame([{"fish_id": "f1", "length_m": 0.6, "weight_kg": 2.5, "height_m": 0.16, "width_m": 0.07,
                          "hours_post_mortem": 10.0, "drop_t_s": 0.0, "drop_x_m": 0.5, "drop_y_m": y_m,
                          "drop_yaw_rad": 0.0, "drop_z_m": 0.02}])
    tracks = pd.DataFrame({"t_s": t, "fish_id": "f1", "x_m": 0.5 + fish_mps * t, "y_m": y_m, "yaw_rad": 0.0})
    belts = pd.DataFrame({"t_s": t, "conveyor_id": "c1", "setpoint_mps": belt_mps, "speed_mps": belt_mps})
    run = Run("r1", 10.0, "", fish, tracks=tracks, belts=belts)
    return Dataset("hand", "", line, KpiSettings(outfeed_photoeye="pe"), [run])


@pytest.mark.parametrize("y_m, touching", [(0.25 - 0.08 - 0.002, 1.0), (0.0, 0.0), (0.25 - 0.08 - 0.010, None)])
def test_the_rows_read_a_fish_s_slip_and_whether_its_flank_is_at_a_guide(y_m: float, touching: float | None):
    rows = guide_rows(one_run_dataset(y_m, fish_mps=0.46))
    if touching is None:  # 10 mm from the guide: tracking noise cannot tell, so no row
        assert rows.empty
        return
    # tracked from x = 0.5 m, wholly on the belt (its ends 5 cm inside) up to 2.65 m: the stretches of 0.25 m
    # from 0.5 m on
    assert rows["x_m"].min() == pytest.approx(0.625) and rows["x_m"].max() == pytest.approx(2.625)
    assert rows["slip_mps"].to_numpy() == pytest.approx(0.04, abs=1e-9)  # 0.5 m/s belt, 0.46 m/s fish
    assert (rows["touching"] == touching).all()
    gap = 0.002 if touching else 0.25 - 0.08
    assert rows["guide_gap_m"].to_numpy() == pytest.approx(gap, abs=1e-9)
    assert {"run_id", "fish_id", "conveyor_id", "hours_post_mortem", "weight_kg", "length_m", "heading",
            "t_in_run_s", "belt_speed_mps"} <= set(rows.columns)


def test_its_terms_are_the_guide_friction_at_each_end():
    cand = CANDIDATES["guide_wear"]
    base = PlantParams()
    terms = cand.terms({"rise": 2.0}, Terms(base, {}))
    assert terms["guide_friction_outfeed_over_infeed"] == pytest.approx(3.0)
    assert terms["guide_friction_outfeed"] == pytest.approx(3.0 * base.friction.fish_guide)
    assert cand.params(base, 2.0).extensions.guide_wear.rise == 2.0
    assert "rise = 2" in cand.fragment({"rise": 2.0}, base)


def test_the_extension_is_fitted_by_simulating_the_runs_with_guide_contact_only(monkeypatch):
    """Stand-in simulations whose error is (rise - 2)^2 per run: only the runs in which fish touched a guide are
    simulated (those of fish alone carry no signal), at the grid's strengths; the fit finds the hidden rise between
    them and carries over to held-out runs."""
    from fishfmu.analysis import extension_fit

    contact = ["r1", "r2", "r3", "r4"]
    rows = pd.DataFrame({"run_id": contact + ["r5", "r6"], "touching": [1.0, 1.0, 1.0, 1.0, 0.0, 0.0]})
    monkeypatch.setattr(guide, "guide_rows", lambda dataset: rows)

    def residual(run_id: str, rise: float) -> SimpleNamespace:
        e = (rise - 2.0) ** 2 + 0.1
        return SimpleNamespace(run_id=run_id, error=None, squares=lambda group, e=e: (e, 10))

    simulated: list[tuple[str, float]] = []

    def resimulate_many(line, runs, params, **kw):
        simulated.extend((r.id, p.extensions.guide_wear.rise) for r, p in zip(runs, params))
        return [(r.id, p.extensions.guide_wear.rise) for r, p in zip(runs, params)]

    monkeypatch.setattr(extension_fit, "resimulate_many", resimulate_many)
    monkeypatch.setattr(extension_fit, "residuals_of", lambda sub, sims: [residual(r, v) for r, v in sims])
    runs = [SimpleNamespace(id=f"r{i}") for i in range(1, 7)]
    dataset = SimpleNamespace(runs=runs, line=None, subset=lambda rs: rs)
    cal = SimpleNamespace(params=PlantParams(), after=[residual(r.id, 0.0) for r in runs], fit_runs=["r5", "r6"])
    ctx = SimpleNamespace(dataset=dataset, cal=cal, pool=None, rng=np.random.default_rng(0), say=lambda s: None)
    cand = CANDIDATES["guide_wear"]
    fit = cand.fit(cand, ctx)
    assert {r for r, _ in simulated} == set(contact)
    assert sorted({v for _, v in simulated}) == sorted(cand.grid)
    assert fit.values["rise"] == pytest.approx(2.0, abs=1e-6)  # the parabola through 1, 3 and the off value 0
    assert fit.confirmed and not fit.at_grid_end
