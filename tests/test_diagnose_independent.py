"""Diagnose on data nobody here simulated: a cut-down dataset of the independent simulator of the pilot line
(``../shared/data/dev``, another physics engine, one hidden effect) must be diagnosed as its label says,
calibration first, as a user would run it (``fishfmu diagnose`` with no options).

CI-sized: two runs with most fish alone cut to the fish dropped in their first 14 s, and the two runs with
the most touching fish whole (what drive droop and adhesion show in)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plant.contract.measured import Dataset, read_dataset, write_dataset

from fishfmu.analysis.calibrate import choose_fit_runs, measured_rows
from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.diagnose_report import write_diagnosis
from tests.test_calibrate import _cut

DEV = Path(__file__).resolve().parents[2] / "shared" / "data" / "dev"


def _small(name: str, out: Path) -> Path:
    """Two runs with most fish alone (cut) and the two with the fewest (whole), chosen from the measured tracks."""
    full = read_dataset(DEV / name)
    fit, held = choose_fit_runs(measured_rows(full))
    alone_first = [r for r in full.runs if r.id in fit[:2]]
    crowded = [r for r in full.runs if r.id in held[:2]]
    cut = _cut(Dataset(full.name, full.description, full.line, full.kpi, alone_first), 2, 14.0, 32.0)
    write_dataset(Dataset(full.name, full.description, full.line, full.kpi, cut.runs + crowded), out)
    return out


@pytest.mark.skipif(not (DEV / "dev_droop").exists(), reason="../shared/data/dev not present")
def test_drive_droop_in_independent_data_is_named_with_a_held_out_gain(tmp_path: Path) -> None:
    truth = json.loads((DEV / "dev_droop.truth.json").read_text())
    assert truth["effect"] == "drive_droop"
    d = diagnose(read_dataset(_small("dev_droop", tmp_path / "data")), workers=2)
    doc = json.loads(write_diagnosis(d, tmp_path / "out")["json"].read_text())
    assert doc["cause"] == "drive_droop", doc["decision"]
    # named by its test: the sag follows the load on runs the term was not fitted on
    named = next(c for c in doc["candidates"] if c["name"] == "drive_droop")
    assert named["significant"] and named["heldout_gain_ci95"][0] > 0.0, named
    # the extended model does better on the held-out runs as a whole and makes none of them worse (with four runs,
    # two of them nearly empty, the bootstrap interval of its gain reaches below zero: the report says so)
    assert doc["heldout"]["gain"] > 0.5 and doc["heldout"]["rms_after"] < doc["heldout"]["rms_before"], doc["heldout"]
    assert min(doc["heldout"]["gain_by_run"].values()) > -0.01, doc["heldout"]
    # the label: speed lost in proportion to the fish carried, 4 % of the belt's speed per 10 kg; the fitted
    # loss per kg (the drive residual against the simulated mass on each belt) grows with each belt's speed
    per_kg = [doc["parameters"][f"droop_per_kg[{c}]"]["value"] for c in ("c1", "c2", "c3", "c4")]
    assert all(v > 0.0 for v in per_kg) and per_kg[3] > per_kg[0], per_kg
