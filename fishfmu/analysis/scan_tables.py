"""The tables the unexplained-discrepancy scan reads (:mod:`fishfmu.analysis.scan`): the judge's rows of the
measured data with each fish's weight, length and arrival, and the lags of fish alone across transfers against the
calibrated model."""

from __future__ import annotations

import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.residuals import RunResiduals, alone


def _fish_table(dataset: Dataset) -> pd.DataFrame:
    frames = [r.fish.assign(run_id=r.id) for r in dataset.runs]
    f = pd.concat(frames, ignore_index=True)
    return f[["run_id", "fish_id", "weight_kg", "length_m", "drop_t_s"]].rename(columns={"drop_t_s": "t_in_run_s"})


def _belt_speeds(dataset: Dataset) -> pd.DataFrame:
    rows = [{"run_id": r.id, "conveyor_id": c, "belt_speed_mps": float(g["speed_mps"].median())}
            for r in dataset.runs if len(r.belts) for c, g in r.belts.groupby("conveyor_id")]
    return pd.DataFrame(rows, columns=["run_id", "conveyor_id", "belt_speed_mps"])


def scan_tables(dataset: Dataset, rows: dict[str, pd.DataFrame], after: list[RunResiduals]) -> dict[str, pd.DataFrame]:
    """The scan's tables: the judge's rows (measured data, and the pairs of the runs re-simulated with the calibrated
    model) with each fish's weight, length and arrival, and the lags of fish alone across transfers against the
    calibrated model (``after``)."""
    fish = _fish_table(dataset)
    speeds = _belt_speeds(dataset)
    out: dict[str, pd.DataFrame] = {}
    drops = rows.get("drops")
    if drops is not None and len(drops):
        drops = drops.drop(columns=[c for c in ("weight_kg", "length_m", "t_in_run_s") if c in drops.columns])
        out["drops"] = drops.merge(fish, on=["run_id", "fish_id"], how="left").assign(
            conveyor_id=dataset.line.conveyors[0].id)
    for name in ("edges", "guides"):
        if rows.get(name) is not None and len(rows[name]):
            out[name] = rows[name]
    passages = rows.get("passages")
    if passages is not None and len(passages):
        out["passages"] = passages.merge(fish, on=["run_id", "fish_id"], how="left")
    if rows.get("drive") is not None and len(rows["drive"]):
        out["drive"] = rows["drive"]
    if rows.get("pairs") is not None and len(rows["pairs"]):
        out["pairs"] = rows["pairs"]
    if rows.get("model_pairs") is not None and len(rows["model_pairs"]):
        out["model_pairs"] = rows["model_pairs"]
    lags = [alone(b.rows).assign(run_id=b.run_id) for b in after if not b.error and len(b.rows)]
    if lags:
        t = pd.concat(lags, ignore_index=True)
        t = t[t["belt"] > 0].drop(columns=["length_m"], errors="ignore")
        t = t.merge(fish, on=["run_id", "fish_id"], how="left").merge(speeds, on=["run_id", "conveyor_id"], how="left")
        order = [c.id for c in dataset.line.conveyors]
        upstream = speeds.rename(columns={"conveyor_id": "upstream", "belt_speed_mps": "upstream_mps"})
        t = t.assign(upstream=t["conveyor_id"].map(dict(zip(order[1:], order[:-1])))).merge(
            upstream, on=["run_id", "upstream"], how="left").drop(columns="upstream")
        t["speed_step_mps"] = t["belt_speed_mps"] - t.pop("upstream_mps")
        t["speed_step_sq_m2ps2"] = t["speed_step_mps"] ** 2
        out["transfers"] = t
    return out
