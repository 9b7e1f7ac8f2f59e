"""``fishfmu compare``: what the simulation gets wrong on measured runs, side by side.

Every run of a dataset is re-simulated with the same fish, drops and measured belt speeds
(:mod:`fishfmu.analysis.resim`); then, per run and over the dataset:

- the KPIs, measured and simulated;
- each fish's arrival at every photo-eye, measured and simulated;
- track errors: the simulated mid-point and heading at each measured sample, minus the measured;
- belt speed errors: the drive FMU fed the logged setpoints (and the simulated belt loads) against
  the logged belt speeds.

Error measures are given per run and as mean, sd, min and max across runs.

A run of a line with devices but without their command log (``device_commands.csv``) cannot be replayed as it ran:
its re-simulation keeps the devices home.  What depends on them is then not compared, never reported as model error
(:func:`device_dependent`): the KPIs the devices change (every outfeed KPI when a device sits before the outfeed
beam), arrivals at photo-eyes from the first device on, track samples from there on.  ``not_replayed`` says which
runs and why (compare.json, kpis.csv's ``note``, the report, the command's output).  The re-simulations
record the fish bodies' poses, so that each run gets a 3D replay page with the measured fish drawn
as ghosts over the simulated ones (``replay/<run_id>.html``, linked from the report).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from plant.contract.kpis import KPI_KEYS as ALL_KPI_KEYS, arrival_times, compute_kpis
from plant.contract.line import KpiSettings, Line
from plant.contract.measured import Dataset, Run, write_dataset
from plant.sim.params import PlantParams

from fishfmu.analysis.drive_response import drive_residuals
from fishfmu.analysis.residuals import concat_typed, track_errors, typed_frame
from fishfmu.analysis.resim import (Resim, drive_check, measured_data_plant, not_resimulated, resimulate_many,
                                    unreplayed_devices)
from fishfmu.output.atomic import json_safe, write_json_atomic, write_text_atomic, write_tree_atomic
from fishfmu.output.replay import write_compare_replay
from fishfmu.session import Interrupted

KPI_KEYS = tuple(k for k in ALL_KPI_KEYS if k not in ("fish_in", "gap_min_m", "gap_p10_m"))
"""The KPIs compared between a measured run and its re-simulation (fish_in is the same by construction)."""


@dataclass
class Comparison:
    dataset: Dataset
    resims: list[Resim]
    kpis: pd.DataFrame
    """run_id, kpi, measured, simulated, error."""
    arrivals: pd.DataFrame
    """run_id, fish_id, sensor_id, measured_t_s, simulated_t_s, error_s."""
    track: pd.DataFrame
    """Track errors at every measured sample (run_id, fish_id, t_s, ex_m, ey_m, eyaw_rad, since_drop_s)."""
    belts: pd.DataFrame
    """run_id, conveyor_id, t_s, setpoint, measured, model speeds and load."""
    measures: pd.DataFrame
    """One row per run and error measure."""
    not_replayed: dict[str, str] | None = None
    """Run id -> why its devices could not be replayed (what depends on them is left out of the comparison)."""

    def summary(self) -> pd.DataFrame:
        """Each error measure over the runs: mean, sd, min, max."""
        g = self.measures.groupby("measure")["value"]
        return pd.DataFrame({"mean": g.mean(), "sd": g.std(ddof=1), "min": g.min(), "max": g.max(),
                             "runs": g.count()}).reset_index()

    def failure(self) -> str | None:
        """Which re-simulations failed and why, in one line (``run 'r03': at t = ... s: ...``); None if none did.
        The command writes what was computed for the other runs, then exits 3 with this."""
        failed = [(s.run_id, s.error) for s in self.resims if s.error]
        if not failed:
            return None
        (run_id, error), more = failed[0], failed[1:]
        also = f" (also failed: {', '.join(repr(r) for r, _ in more)}; see compare.json)" if more else ""
        return f"run '{run_id}': {error}{also}"


def simulated_run(run: Run, resim: Resim) -> Run:
    """The re-simulation as a run of the measured-data format (its devices' rejections and commands included)."""
    sim = resim.sim
    return Run(run.id, run.hours_post_mortem, "simulated", sim.fish, sim.tracks, sim.photoeyes, sim.belts,
               **({"rejections": sim.rejections} if sim.rejections is not None else {}),
               device_commands=sim.device_commands)


@dataclass(frozen=True)
class DeviceDependent:
    """What an unreplayed device changes on a line: the KPIs, and the x from which arrivals and tracks."""

    kpis: tuple[str, ...]
    from_x_m: float


def device_dependent(line: Line, kpi: KpiSettings) -> DeviceDependent:
    """The rejections always; every outfeed KPI when a device sits before the outfeed beam (the fish it takes or
    leaves decide what passes there); arrivals and tracks from the first device's x on."""
    first_x_m = min(d.x_m for d in line.devices)
    before_outfeed = first_x_m < line.photoeye(kpi.outfeed_photoeye).x_m
    return DeviceDependent(KPI_KEYS if before_outfeed else ("rejected", "good_rejected"), first_x_m)


def compare_dataset(dataset: Dataset, params: PlantParams | None = None, workers: int | None = None,
                    drive_parameters: dict | None = None) -> Comparison:
    params = params or measured_data_plant()
    try:
        resims = resimulate_many(dataset.line, dataset.runs, [params] * len(dataset.runs), workers, record_poses=True)
    except Interrupted as exc:  # SIGINT/SIGTERM under the command: compare the runs that were re-simulated
        if exc.partial is None:
            raise
        resims = [r if r is not None else not_resimulated(run, f"not re-simulated: stopped by {exc.signal_name}")
                  for run, r in zip(dataset.runs, exc.partial)]
    kpi_rows, arrival_rows, track_rows, belt_rows, measures = [], [], [], [], []
    not_replayed: dict[str, str] = {}
    for run, r in zip(dataset.runs, resims):
        if r.error:
            measures.append({"run_id": run.id, "measure": "simulation failed", "value": np.nan, "note": r.error})
            continue
        sim = simulated_run(run, r)
        km, ks = compute_kpis(run, dataset.line, dataset.kpi), compute_kpis(sim, dataset.line, dataset.kpi)
        unreplayed = unreplayed_devices(dataset.line, run)
        left_out = device_dependent(dataset.line, dataset.kpi) if unreplayed else None
        if unreplayed:
            not_replayed[run.id] = unreplayed
        for k in KPI_KEYS:
            m, s = km.get(k), ks.get(k)
            if left_out is not None and k in left_out.kpis:  # the devices', not the model's: not compared
                kpi_rows.append({"run_id": run.id, "kpi": k, "measured": m, "simulated": np.nan, "error": np.nan,
                                 "note": "not compared: devices not replayed (no device_commands.csv)"})
                continue
            err = (s - m) if (m is not None and s is not None) else np.nan
            kpi_rows.append({"run_id": run.id, "kpi": k, "measured": m, "simulated": s, "error": err, "note": ""})
        am = arrival_times(run, dataset.line)
        asim = arrival_times(sim, dataset.line)
        a = am.merge(asim, on=["fish_id", "sensor_id"], how="outer", suffixes=("_measured", "_simulated"))
        a = a.rename(columns={"t_s_measured": "measured_t_s", "t_s_simulated": "simulated_t_s"})
        a["error_s"] = a["simulated_t_s"] - a["measured_t_s"]
        if left_out is not None:  # beams from the first device on see what the unreplayed devices let through
            after = [p.id for p in dataset.line.photoeyes if p.x_m >= left_out.from_x_m]
            a.loc[a["sensor_id"].isin(after), "error_s"] = np.nan
        arrival_rows.append(a[["fish_id", "sensor_id", "measured_t_s", "simulated_t_s", "error_s"]].assign(run_id=run.id))
        measured_tracks = run.tracks if left_out is None else run.tracks[run.tracks["x_m"] < left_out.from_x_m]
        e = track_errors(measured_tracks, sim.tracks)
        drops = run.fish.set_index("fish_id")["drop_t_s"]
        e["since_drop_s"] = e["t_s"] - e["fish_id"].map(drops)
        track_rows.append(e.assign(run_id=run.id))
        for c in dataset.line.conveyors:
            chk = drive_check(run, r.loads, c.id, drive_parameters)
            belt_rows.append(chk.assign(run_id=run.id, conveyor_id=c.id))
            steady = drive_residuals(chk)
            if len(steady):
                measures.append({"run_id": run.id, "measure": f"belt speed RMS error {c.id} [m/s]",
                                 "value": float(np.sqrt(np.mean(steady["residual_mps"] ** 2)))})
        if len(e):
            measures += [
                {"run_id": run.id, "measure": "track RMS error along [m]", "value": float(np.sqrt(np.mean(e["ex_m"] ** 2)))},
                {"run_id": run.id, "measure": "track RMS error across [m]", "value": float(np.sqrt(np.mean(e["ey_m"] ** 2)))},
                {"run_id": run.id, "measure": "heading RMS error [deg]",
                 "value": float(np.degrees(np.sqrt(np.mean(e["eyaw_rad"] ** 2))))}]
        err = a["error_s"].dropna()
        if len(err):
            measures.append({"run_id": run.id, "measure": "arrival RMS error [s]", "value": float(np.sqrt(np.mean(err**2)))})
            measures.append({"run_id": run.id, "measure": "arrival mean error [s]", "value": float(err.mean())})
        for k in ("singulation_rate", "throughput_time_s"):
            m, s = km.get(k), ks.get(k)
            if m is not None and s is not None and not (left_out is not None and k in left_out.kpis):
                measures.append({"run_id": run.id, "measure": f"{k} error", "value": float(s - m)})
    f, o = float, object  # explicit dtypes: an empty table must not turn a concatenation's columns into object
    return Comparison(
        dataset, resims,
        typed_frame(kpi_rows, {"run_id": o, "kpi": o, "measured": f, "simulated": f, "error": f, "note": o}),
        concat_typed(arrival_rows, {"run_id": o, "fish_id": o, "sensor_id": o, "measured_t_s": f, "simulated_t_s": f,
                                    "error_s": f}),
        concat_typed(track_rows, {"run_id": o, "fish_id": o, "t_s": f, "ex_m": f, "ey_m": f, "eyaw_rad": f,
                                  "since_drop_s": f}),
        concat_typed(belt_rows, {"run_id": o, "conveyor_id": o, "t_s": f, "setpoint_mps": f, "measured_mps": f,
                                 "model_mps": f}),
        typed_frame(measures, {"run_id": o, "measure": o, "value": f, "note": o}), not_replayed)


def write_replays(c: Comparison, folder: Path) -> dict[str, Path]:
    """One replay page per re-simulated run (run id -> page): the simulated fish and the measured ones
    over them (:func:`fishfmu.output.replay.write_compare_replay`).  Runs whose re-simulation failed, or
    that recorded no poses, get none."""
    pages = {}
    for run, r in zip(c.dataset.runs, c.resims):
        if r.error or r.sim.poses is None or len(r.sim.poses["t_s"]) == 0:
            continue
        pages[run.id] = write_compare_replay(c.dataset.line, c.dataset.name, run, simulated_run(run, r), r.sim.poses,
                                             folder / f"{run.id}.html")
    return pages


def write_comparison(c: Comparison, out: Path) -> dict[str, Path]:
    """Tables (CSV), plots (PNG), a report (HTML), the simulated runs (measured-data format) and a
    3D replay page per run (``replay/``)."""
    # slow and only for the report: matplotlib
    from fishfmu.analysis.compare_report import write_compare_report
    paths = {}
    kpis = c.kpis if c.not_replayed else c.kpis.drop(columns="note")  # the note only where a run needs it
    for name, df in (("kpis", kpis), ("arrivals", c.arrivals), ("error_measures", c.measures),
                     ("error_summary", c.summary())):
        paths[name] = out / f"{name}.csv"
        write_text_atomic(paths[name], df.to_csv(index=False, float_format="%.6g"))
    sim_runs = [simulated_run(r, s) for r, s in zip(c.dataset.runs, c.resims) if not s.error]
    write_tree_atomic(out / "simulated", lambda tmp: write_dataset(Dataset(
        c.dataset.name + "-simulated", "re-simulated by fishfmu compare", c.dataset.line, c.dataset.kpi, sim_runs), tmp))
    paths["simulated"] = out / "simulated"
    summary = c.summary()
    write_json_atomic(out / "compare.json", {
        "dataset": c.dataset.name, "runs": len(c.dataset.runs),
        "failed": {s.run_id: s.error for s in c.resims if s.error},
        # runs whose devices the re-simulation could not fire: what they change is left out, not model error
        "not_replayed": {run_id: {"reason": why, "kpis_not_compared": list(left_out.kpis),
                                  "arrivals_and_tracks_from_x_m": left_out.from_x_m}
                         for run_id, why in (c.not_replayed or {}).items()
                         for left_out in [device_dependent(c.dataset.line, c.dataset.kpi)]},
        # NaN (an sd over one run, a measure no run has) is null
        "error_summary": {row.measure: {k: json_safe(float(getattr(row, k))) for k in ("mean", "sd", "min", "max")}
                          for row in summary.itertuples()}})
    replays = write_replays(c, out / "replay")
    if replays:
        paths["replay"] = out / "replay"
    paths["report"] = write_compare_report(c, out, replays)
    return paths
