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

import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from plant.contract.measured import read_dataset
from plant.validation import read_toml

from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.recovery import RECOVERED_WITHIN, recovery, truth_terms
from fishfmu.analysis.synthetic import (EFFECTS, SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset,
                                        synthetic_base)


def run_bench(seeds: list[int], effects: tuple[str, ...] = EFFECTS, strength: float = 1.0, workers: int = 2,
              on_row: Callable[[dict], None] | None = None) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        for effect in effects:
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                base = synthetic_base()
                path = make_dataset(Path(tmp) / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS,
                                    seed=seed, strength=strength, base=base)
                d = diagnose(read_dataset(path), base, workers=workers, seed=seed, calibrate=False)  # base: known
                rows.append({"effect": effect, "seed": seed, "cause": d.cause, "correct": d.cause == effect,
                             "heldout_gain": d.fit.heldout_gain if d.fit else 0.0, "wall_s": time.perf_counter() - t0})
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
               "adhesion": "adhesion", "directional_friction": "directional_friction"}
"""A label's effect (``NAME.truth.json``) as the candidate that names it."""


def read_splits(recipe: Path | None) -> dict[str, str]:
    """Dataset name -> its split (``dev``, ``heldout``) from a benchmark recipe (``docs/diagnose-bench/recipe.toml``)."""
    if recipe is None:
        return {}
    doc = read_toml(recipe)
    return {str(d["name"]): str(d.get("split", "dev")) for d in doc.get("dataset", [])}


def bench_labelled(folder: Path, workers: int = 2, on_row: Callable[[dict], None] | None = None,
                   splits: dict[str, str] | None = None, only: str | None = None,
                   on_done: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """Diagnose every labelled dataset in ``folder`` as a user would (calibrating first); the confusion table,
    accuracy, false-positive rate and times, overall and per split (``splits``: name -> split; ``only``: that
    split alone). ``on_done(doc)`` after each dataset: the results so far (a long benchmark keeps what it did)."""
    splits = splits or {}
    rows = []
    for truth_file in sorted(folder.glob("*.truth.json")):
        data = folder / truth_file.name.removesuffix(".truth.json")
        split = splits.get(data.name, "all")
        if not data.is_dir() or (only is not None and split != only):
            continue
        truth = json.loads(truth_file.read_text())
        effect = TRUTH_NAMES.get(truth["effect"], truth["effect"])
        t0 = time.perf_counter()
        dataset = read_dataset(data)
        d = diagnose(dataset, workers=workers)
        truth_in_terms = truth_terms(effect, truth.get("magnitude", {}), dataset)
        rows.append({"dataset": data.name, "split": split, "effect": effect, "cause": d.cause,
                     "correct": d.cause == effect,
                     "tests": {t.candidate: {"p": t.p_value, "gain": t.heldout_gain, "ci95": list(t.heldout_gain_ci95),
                                             "effect": t.effect} for t in d.judgement.tests},
                     "fit": ({"gain": d.fit.heldout_gain, "ci95": list(d.fit.heldout_gain_ci95), "values": d.fit.values}
                             if d.fit else None),
                     "extension": d.extension, "terms": d.terms, "truth_terms": truth_in_terms,
                     "recovery": recovery(effect, d.terms, truth_in_terms) if d.cause == effect else {},
                     "calibration": d.calibration.changed(d.calibration.base) if d.calibration else {},
                     "wall_s": time.perf_counter() - t0})
        if on_row is not None:
            row = rows[-1]
            on_row({k: row[k] for k in ("dataset", "split", "effect", "cause", "extension", "wall_s")}
                   | {"p": {n: round(t["p"], 3) for n, t in row["tests"].items()}} | {"recovery": row["recovery"]})
        if on_done is not None:
            on_done(labelled_document(rows, folder))
    return labelled_document(rows, folder)


def labelled_document(rows: list[dict], folder: Path) -> dict[str, Any]:
    """Confusion tables, accuracy and false-positive rate (datasets without an effect named as one), overall and
    per split, and the times."""
    table = pd.DataFrame(rows)
    if table.empty:
        return {"runs": [], "accuracy": {}, "overall": float("nan"), "confusion": {}, "splits": {}}

    def part(t: pd.DataFrame) -> dict[str, Any]:
        none = t[t["effect"] == "none"]
        return {"datasets": len(t), "correct": int(t["correct"].sum()), "overall": float(t["correct"].mean()),
                "accuracy": t.groupby("effect")["correct"].mean().to_dict(),
                "confusion": pd.crosstab(t["effect"], t["cause"]).to_dict(),
                "false_positives": int((none["cause"] != "none").sum()), "no_effect_datasets": len(none),
                "wall_s": {"mean": float(t["wall_s"].mean()), "max": float(t["wall_s"].max())}}

    return {"runs": rows, **part(table), "splits": {s: part(t) for s, t in table.groupby("split")},
            "folder": str(folder)}


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    lines = []
    parts = [("all", doc)] + sorted(doc.get("splits", {}).items()) if len(doc.get("splits", {})) > 1 else [("all", doc)]
    for name, part in parts:
        if not part.get("confusion"):
            continue
        confusion = pd.DataFrame(part["confusion"]).fillna(0).astype(int)
        lines += [f"-- {name}", confusion.to_string(), pd.Series(part["accuracy"], name="accuracy").to_string(),
                  f"overall: {part['overall']:.0%}"]
        if "no_effect_datasets" in part:
            lines.append(f"no-effect datasets named as an effect: {part['false_positives']} of "
                         f"{part['no_effect_datasets']}; time per dataset {part['wall_s']['mean']:.0f} s on average, "
                         f"{part['wall_s']['max']:.0f} s at most")
    rows = [r for r in doc.get("runs", []) if r.get("fit") is not None and r.get("cause") == r.get("effect")]
    if rows:
        lines.append("-- the named cause's extension against the base on held-out runs, its strength against the truth")
        for r in rows:
            rec = r.get("recovery") or {}
            lo, hi = r["fit"]["ci95"]
            lines.append(f"{r['dataset']}: {r['effect']} extension {r.get('extension', '?')}, held-out gain "
                         f"{r['fit']['gain']:.1%} [{lo:.1%}, {hi:.1%}]" + (
                             f"; {rec['term']} fitted {rec['fitted']:.3g}, truth {rec['truth']:.3g} (x{rec['ratio']:.2f}, "
                             + ("within" if rec["within"] else "outside") + f" x{RECOVERED_WITHIN:g})" if rec else ""))
    return lines
