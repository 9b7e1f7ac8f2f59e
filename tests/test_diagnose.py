"""Hidden effects: a dataset simulated with one effect on (or none), degraded like a line's instruments
degrade it, must be diagnosed as that effect (or none), with a gain on held-out runs.

The analysis is not told the effect; each case takes under a minute on 2 cores (see
``python -m fishfmu.bench.diagnose`` for the larger benchmark over many seeds).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plant.measured import read_dataset

from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.diagnose_report import write_diagnosis
from fishfmu.analysis.synthetic import SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset


@pytest.mark.parametrize("effect", ["none", "mucus_friction", "rigor_mortis", "adhesion", "drive_droop"])
def test_diagnose_names_the_hidden_effect_with_a_held_out_gain(effect: str, tmp_path: Path):
    path = make_dataset(tmp_path / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS, seed=11)
    dataset = read_dataset(path)  # through the readers, like any customer's data
    d = diagnose(dataset, workers=2, calibrate=False)  # made by this simulator: its base is the model's
    paths = write_diagnosis(d, tmp_path / "out")
    doc = json.loads(paths["json"].read_text())
    assert doc["cause"] == effect, doc["decision"]
    # the verdict is clear by a margin, not decided by the last bits of rounding: the cause's held-out
    # gain clears the rule's minimum and its interval clears zero, and every other fitted candidate
    # misses one of them by a margin (measured here: none had every candidate's gain below -0.2 %;
    # the named causes: gains 2.6-81 %, interval lower ends 1.9-70 % with six pair runs; adhesion 0.0 % with four)
    min_gain = doc["rules"]["min_gain"]
    for c in doc["candidates"]:
        if c["fitted"] and c["name"] != effect:
            assert c["heldout_gain"] < 0.8 * min_gain or c["heldout_gain_ci95"][0] < -0.01, c
    if effect == "none":
        assert doc["parameters"] == {} and "no significant discrepancy" in doc["decision"]
        assert "no extension" in paths["fragment"].read_text()
    else:
        assert doc["heldout"]["gain"] > 1.1 * min_gain and doc["heldout"]["gain_ci95"][0] > 0.01, doc["heldout"]
        assert doc["heldout"]["rms_after"] < doc["heldout"]["rms_before"]
        fragment = paths["fragment"].read_text()
        assert effect in fragment or "belt_slip" in fragment
        assert doc["ranking"][0] == effect
