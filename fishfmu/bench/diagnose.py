"""Benchmark of ``diagnose`` on hidden effects: how often it names the right cause, over many seeds.

    fishfmu bench diagnose --seeds 5 --json bench-results/diagnose_bench.json
    fishfmu bench diagnose --labelled ../shared/data/dev --json bench-results/diagnose_dev.json

With ``--labelled DIR``: every dataset folder in DIR that has a ``NAME.truth.json`` beside it (labelled data,
e.g. from an independent simulator) is diagnosed as a user would (calibrating first), and the named cause
compared with the label; the time of each diagnosis is recorded.

Each effect (and none) is simulated on the small line and run design of ``fishfmu.analysis.synthetic`` (that of tests/test_diagnose.py) with
a different seed per repetition (different fish, drops, noise), diagnosed without being told, and
the named cause recorded; the result is a confusion table and the accuracy per effect.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from plant.measured import read_dataset

from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.synthetic import EFFECTS, SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset


def run_bench(seeds: list[int], effects: tuple[str, ...] = EFFECTS, strength: float = 1.0, workers: int = 2,
              on_row: Callable[[dict], None] | None = None) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        for effect in effects:
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                path = make_dataset(Path(tmp) / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS,
                                    seed=seed, strength=strength)
                d = diagnose(read_dataset(path), workers=workers, seed=seed, calibrate=False)  # base: the model's
                fit = next((f for f in d.fits if f.name == d.cause), None)
                rows.append({"effect": effect, "seed": seed, "cause": d.cause, "correct": d.cause == effect,
                             "heldout_gain": fit.heldout_gain if fit else 0.0, "wall_s": time.perf_counter() - t0})
                if on_row is not None:
                    on_row(rows[-1])
    return pd.DataFrame(rows)


def bench(seeds: int = 5, first_seed: int = 100, strength: float = 1.0, workers: int = 2,
          on_row: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """The confusion table and accuracy per effect over ``seeds`` seeds from ``first_seed``."""
    table = run_bench(list(range(first_seed, first_seed + seeds)), strength=strength, workers=workers, on_row=on_row)
    confusion = pd.crosstab(table["effect"], table["cause"])
    accuracy = table.groupby("effect")["correct"].mean()
    return {"runs": table.to_dict(orient="records"), "accuracy": accuracy.to_dict(),
            "overall": float(table["correct"].mean()), "confusion": confusion.to_dict(), "strength": strength}


TRUTH_NAMES = {"none": "none", "mucus": "mucus_friction", "rigor": "rigor_mortis", "drive_droop": "drive_droop",
               "adhesion": "adhesion"}
"""A label's effect (``NAME.truth.json``) as the candidate that names it."""


def bench_labelled(folder: Path, workers: int = 2, on_row: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """Diagnose every labelled dataset in ``folder``; the confusion table, accuracy and times."""
    import json
    rows = []
    for truth_file in sorted(folder.glob("*.truth.json")):
        data = folder / truth_file.name.removesuffix(".truth.json")
        if not data.is_dir():
            continue
        label = json.loads(truth_file.read_text())["effect"]
        effect = TRUTH_NAMES.get(label, label)
        t0 = time.perf_counter()
        d = diagnose(read_dataset(data), workers=workers)
        fit = next((f for f in d.fits if f.name == d.cause), None)
        rows.append({"dataset": data.name, "effect": effect, "cause": d.cause, "correct": d.cause == effect,
                     "heldout_gain": fit.heldout_gain if fit else 0.0,
                     "heldout_gain_ci95": list(fit.heldout_gain_ci95) if fit else None,
                     "candidates": {f.name: {"gain": f.heldout_gain, "ci95": list(f.heldout_gain_ci95),
                                             "values": f.values} for f in d.fits},
                     "calibration": d.calibration.changed(d.calibration.base) if d.calibration else {},
                     "wall_s": time.perf_counter() - t0})
        if on_row is not None:
            row = rows[-1]
            on_row({k: row[k] for k in ("dataset", "effect", "cause", "heldout_gain", "wall_s")}
                   | {"gains": {n: f"{c['gain']:.0%} [{c['ci95'][0]:.0%}, {c['ci95'][1]:.0%}]"
                                for n, c in row["candidates"].items()}})
    table = pd.DataFrame(rows)
    if table.empty:
        return {"runs": [], "accuracy": {}, "overall": float("nan"), "confusion": {}}
    return {"runs": rows, "accuracy": table.groupby("effect")["correct"].mean().to_dict(),
            "overall": float(table["correct"].mean()),
            "confusion": pd.crosstab(table["effect"], table["cause"]).to_dict(), "folder": str(folder)}


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    confusion = pd.DataFrame(doc["confusion"]).fillna(0).astype(int)
    return [confusion.to_string(), pd.Series(doc["accuracy"], name="accuracy").to_string(),
            f"overall: {doc['overall']:.0%}"]
