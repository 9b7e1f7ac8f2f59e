"""Hidden effects: a dataset simulated with one effect on (or none), degraded like a line's instruments
degrade it, must be diagnosed as that effect (or none), with a gain on held-out runs.

The analysis is not told the effect; each case takes about a minute on 2 cores (see
``python -m fishfmu.diagnose_bench`` for the larger benchmark over many seeds).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plant.line import KpiSettings, Line
from plant.measured import read_dataset

from fishfmu.diagnose import diagnose
from fishfmu.diagnose_report import write_diagnosis
from fishfmu.synthetic import make_dataset

LINE = Line.model_validate({"guide_width_m": 0.5, "conveyors": [
    {"id": "c1", "x_start_m": 0.0, "length_m": 1.2, "width_m": 0.5, "z_top_m": 0.0},
    {"id": "c2", "x_start_m": 1.21, "length_m": 1.0, "width_m": 0.5, "z_top_m": -0.02},
    {"id": "c3", "x_start_m": 2.22, "length_m": 1.0, "width_m": 0.5, "z_top_m": -0.04}],
    "photoeyes": [{"id": "pe1", "x_m": 1.1, "z_m": 0.015}, {"id": "pe2", "x_m": 2.12, "z_m": -0.005},
                  {"id": "pe3", "x_m": 3.12, "z_m": -0.025}]})
KPI = KpiSettings(outfeed_photoeye="pe3")
SPEEDS = [0.3, 0.7, 1.2]
# fish alone at eight ages (what friction effects show in), and touching pairs (what adhesion shows in)
RUNS = [(h, "sparse", 2) for h in (1.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0, 72.0)] + \
       [(12.0, "pairs", 6), (36.0, "pairs", 6), (60.0, "pairs", 6)]


@pytest.mark.parametrize("effect", ["none", "direction_friction", "mucus_friction", "rigor_mortis", "adhesion",
                                    "drive_droop"])
def test_diagnose_names_the_hidden_effect_with_a_held_out_gain(effect: str, tmp_path: Path):
    path = make_dataset(tmp_path / "data", effect, LINE, KPI, RUNS, SPEEDS, seed=11)
    dataset = read_dataset(path)  # through the readers, like any customer's data
    d = diagnose(dataset, workers=2)
    paths = write_diagnosis(d, tmp_path / "out")
    doc = json.loads(paths["json"].read_text())
    assert doc["cause"] == effect, doc["decision"]
    if effect == "none":
        assert doc["parameters"] == {} and "no significant discrepancy" in doc["decision"]
        assert "no extension" in paths["fragment"].read_text()
    else:
        assert doc["heldout"]["gain"] > 0.0 and doc["heldout"]["gain_ci95"][0] > 0.0
        assert doc["heldout"]["rms_after"] < doc["heldout"]["rms_before"]
        fragment = paths["fragment"].read_text()
        assert effect in fragment or "belt_slip" in fragment
        assert doc["ranking"][0] == effect
