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
from plant.contract.measured import read_dataset

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


@pytest.mark.skipif(not TRUTHS, reason="../shared/data/dev not present")
def test_photoeye_passages_show_rigor_in_independent_data() -> None:
    # The signature that tells rigor from mucus, read from data nobody here made: in the rigor dataset the
    # beams flicker over fish in rigor (8-36 h post mortem: stiff, they do not lie into the belt) and not over
    # fresh or resolved ones (1 h, 72 h); in the dataset without an effect they block throughout at every age.
    from fishfmu.analysis.residuals import photoeye_passages

    def blocked_by_hours(name: str) -> pd.Series:
        ds = read_dataset(DATA / "dev" / name)
        shares = {}
        for run in ds.runs:
            p = photoeye_passages(run.tracks, run.photoeyes, run.fish, ds.line)
            if len(p) >= 20:  # the sparse runs: most passages are of a fish alone
                shares.setdefault(run.hours_post_mortem, []).extend(p["blocked"])
        return pd.Series({h: float(pd.Series(v).mean()) for h, v in shares.items()}).sort_index()

    rigor, none = blocked_by_hours("dev_rigor"), blocked_by_hours("dev_none")
    in_rigor = rigor[(rigor.index >= 8) & (rigor.index <= 36)]
    out_of_rigor = rigor[(rigor.index < 8) | (rigor.index > 36)]
    assert len(in_rigor) >= 2 and len(out_of_rigor) >= 2
    assert out_of_rigor.min() > 0.99 and in_rigor.max() < out_of_rigor.min() - 0.02
    assert none.min() > 0.99


@pytest.mark.skipif(not TRUTHS, reason="../shared/data/dev not present")
def test_drop_lags_show_slippery_fresh_fish_in_independent_data() -> None:
    # The signature mucus leaves on the drops, read from data nobody here made: fish dropped alone onto the infeed
    # lose more time to it when fresh (slippery slaughter mucus) than a day or more later; in the
    # dataset without an effect they take the same time at every age.
    from fishfmu.analysis.residuals import drop_lags

    def by_hours(name: str) -> pd.DataFrame:
        ds = read_dataset(DATA / "dev" / name)
        rows = []
        for run in ds.runs:
            d = drop_lags(run, ds.line)["drop_lag_s"]
            if len(d) >= 10:  # the sparse runs: fish dropped one at a time
                rows.append({"hours": run.hours_post_mortem, "median": d.median(), "se": d.std() / len(d) ** 0.5})
        return pd.DataFrame(rows).set_index("hours").sort_index()

    mucus, none = by_hours("dev_mucus"), by_hours("dev_none")
    assert len(mucus) >= 4 and len(none) >= 4
    fresh, later = mucus.loc[mucus.index.min()], mucus[mucus.index >= 16]
    assert mucus.index.min() <= 2.0 and len(later) >= 2
    assert (fresh["median"] - later["median"] > 3 * (fresh["se"] ** 2 + later["se"] ** 2) ** 0.5).all()
    assert none["median"].max() - none["median"].min() < 0.01  # s: about 0.12 s at every age (medians: a few fish land badly)
