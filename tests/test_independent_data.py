"""Data nobody here simulated: the datasets of an independent simulator of the pilot line
(``../shared/data/dev``, another physics engine) and the pilot line's own runs go through the
readers and their plausibility checks without a false refusal, and a fault put into such a dataset
is refused naming its file, row and column.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from plant.errors import InputError
from plant.measured import read_dataset

DATA = Path(__file__).parents[2] / "shared" / "data"
TRUTHS = sorted((DATA / "dev").glob("*.truth.json"))


@pytest.mark.skipif(not TRUTHS, reason="../shared/data/dev not present")
@pytest.mark.parametrize("truth", TRUTHS, ids=[t.name.removesuffix(".truth.json") for t in TRUTHS])
def test_independent_datasets_pass_the_plausibility_checks(truth: Path) -> None:
    label = json.loads(truth.read_text())
    ds = read_dataset(truth.with_name(label["dataset"]))
    assert len(ds.runs) == label["runs"]
    assert all(len(r.fish) == label["fish_per_run"] for r in ds.runs)
    conveyors = {c.id for c in ds.line.conveyors}
    assert all(set(r.belts["conveyor_id"]) == conveyors for r in ds.runs)  # every belt logged


@pytest.mark.skipif(not TRUTHS, reason="../shared/data/dev not present")
def test_a_drop_outside_the_line_in_independent_data_is_refused_naming_row_and_column(tmp_path: Path) -> None:
    source = DATA / "dev" / "dev_none"
    copy = tmp_path / "dev_none"
    shutil.copytree(source, copy)
    run = sorted((copy / "runs").iterdir())[0]
    fish = pd.read_csv(run / "fish.csv")
    end_m = max(c.x_start_m + c.length_m for c in read_dataset(source).line.conveyors)
    fish.loc[2, "drop_x_m"] = end_m + 1.0  # a metre past the last belt
    fish.to_csv(run / "fish.csv", index=False)
    with pytest.raises(InputError) as info:
        read_dataset(copy)
    text = str(info.value)
    # the header is line 1, so the third fish (index 2) is on line 4
    assert str(run / "fish.csv") in text and "row 4" in text and "drop_x_m" in text, text
