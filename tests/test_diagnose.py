"""Hidden effects: a dataset simulated with one effect on (or none), degraded like a line's instruments
degrade it, must be diagnosed as that effect (or none), with a gain on held-out runs.

The analysis is not told the effect; each case takes under a minute on 2 cores (see
``python -m fishfmu.bench.diagnose`` for the larger benchmark over many seeds).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plant.contract.measured import read_dataset

from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.diagnose_report import write_diagnosis
from fishfmu.analysis.synthetic import SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset, synthetic_base


@pytest.mark.parametrize("effect", ["none", "mucus_friction", "rigor_mortis", "directional_friction", "adhesion",
                                    "drive_droop"])
def test_diagnose_names_the_hidden_effect_with_a_held_out_gain(effect: str, tmp_path: Path):
    base = synthetic_base()  # a base whose drops do not depend on the fish's heading (see synthetic_base)
    path = make_dataset(tmp_path / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS, seed=11, base=base)
    dataset = read_dataset(path)  # through the readers, like any customer's data
    d = diagnose(dataset, base, workers=2, calibrate=False)  # made by this simulator: its base is known
    paths = write_diagnosis(d, tmp_path / "out")
    doc = json.loads(paths["json"].read_text())
    assert doc["cause"] == effect, doc["decision"]
    alpha = doc["rules"]["alpha"]
    # the verdict is clear by a margin, not decided by the last bits of rounding: every other candidate's test is
    # not significant, and the named one's p-value is well inside the rule
    for c in doc["candidates"]:
        if c["name"] != effect:
            assert not c["significant"], c
    if effect == "none":
        assert doc["parameters"] == {} and "no significant discrepancy" in doc["decision"]
        assert "no extension" in paths["fragment"].read_text()
    else:
        named = next(c for c in doc["candidates"] if c["name"] == effect)
        assert named["significant"] and named["p_value"] <= alpha, named
        assert doc["ranking"][0] == effect
        # the model extended with it carries over to held-out runs
        assert doc["heldout"]["gain"] > 0.02 and doc["heldout"]["gain_ci95"][0] > 0.0, doc["heldout"]
        assert doc["heldout"]["rms_after"] < doc["heldout"]["rms_before"]
        fragment = paths["fragment"].read_text()
        assert effect in fragment or "belt_slip" in fragment or "direction_friction" in fragment
