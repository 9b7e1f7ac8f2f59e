"""Writing a calibration: ``calibration.json``, the fragment ``calibrated.toml`` and the console's summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plant.sim.params import PlantParams

from fishfmu.analysis.calibrate import KNOBS, Calibration, findings
from fishfmu.analysis.resim import fish_model_lines
from fishfmu.output.atomic import json_safe, write_json_atomic, write_text_atomic


def calibration_document(c: Calibration, base: PlantParams) -> dict:
    """calibration.json: what was fitted, on which runs, and the errors before and after."""
    return {
        "fit_runs": c.fit_runs, "heldout_runs": c.heldout_runs,
        "knobs": [{"name": f.name, "description": KNOBS[f.name].description, "value": f.value,
                   "fitted": f.fitted, "fitted_ci95": list(f.ci95), "heldout_gain": f.heldout_gain,
                   "heldout_gain_ci95": list(f.heldout_gain_ci95), "kept": f.kept,
                   "rejected_on_heldout_runs": f.rejected_on_heldout, "implausible": f.implausible,
                   "error_m2_per_value": {f"{k:g}": v for k, v in f.errors.items()}} for f in c.fits],
        "changed": {path: {"model": a, "calibrated": b} for path, (a, b) in c.changed(base).items()},
        "findings": findings(c),
        "lag_rms_m": {"before": c.rms_before_m, "after": c.rms_after_m},
        "track_rms_m": {"before": c.track_rms_before_m, "after": c.track_rms_after_m},
        "drives": [{"conveyor_id": d.conveyor_id, "parameter": "ramp_acceleration", "unit": "m/s2",
                    "model": d.model_mps2, "value": d.value_mps2, "fitted": d.fitted_mps2, "fitted_ci95": list(d.ci95),
                    "heldout_gain": d.heldout_gain, "heldout_gain_ci95": list(d.heldout_gain_ci95), "kept": d.kept,
                    "startups": d.startups, "speed_rms_mps": d.rms_mps} for d in c.drives],
        "timing_s": c.timing_s,
    }


def write_calibration(c: Calibration, base: PlantParams, out) -> dict:
    """``calibrated.toml`` (the fragment) and ``calibration.json`` in the folder ``out``."""
    out = Path(out)
    paths = {"fragment": out / "calibrated.toml", "json": out / "calibration.json"}
    write_text_atomic(paths["fragment"], fish_model_lines(base) + c.fragment(base))
    write_json_atomic(paths["json"], json_safe(calibration_document(c, base)))
    return paths


def summary_lines(c: Calibration, base: PlantParams) -> list[str]:
    """What the calibration changed and what it gained, for the console."""
    lines = []
    for f in c.fits:
        gain = f"held-out gain {f.heldout_gain:.0%} [{f.heldout_gain_ci95[0]:.0%}, {f.heldout_gain_ci95[1]:.0%}]"
        kind = "x" if KNOBS[f.name].off == 1.0 else "+"
        applied = "" if f.value == f.fitted else f", applied {kind}{f.value:.3g}"
        lines.append(f"{f.name}: fitted {kind}{f.fitted:.3g} [{f.ci95[0]:.3g}, {f.ci95[1]:.3g}]{applied}, {gain}"
                     + ("" if f.kept else " (not kept: the held-out runs got worse)" if f.rejected_on_heldout
                        else " (not kept: not physically plausible)" if f.implausible else " (not kept)"))
    for path, (a, b) in c.changed(base).items():
        lines.append(f"  {path}: {a:.4g} -> {b:.4g}")
    lines += [f"finding: {f}" for f in findings(c)]
    for d in c.drives:
        if not np.isfinite(d.fitted_mps2):
            continue
        err = d.rms_mps.get("heldout", {})
        lines.append(f"drive {d.conveyor_id} ramp: fitted {d.fitted_mps2:.3g} m/s2 [{d.ci95[0]:.3g}, {d.ci95[1]:.3g}] "
                     f"(model {d.model_mps2:g}), held-out gain {d.heldout_gain:.0%} [{d.heldout_gain_ci95[0]:.0%}, "
                     f"{d.heldout_gain_ci95[1]:.0%}]" + ("" if d.kept else " (not kept)")
                     + (f"; start-up speed error on the held-out runs {err['before']:.3f} -> {err['after']:.3f} m/s"
                        if d.kept and np.isfinite(err.get("before", np.nan)) else ""))
    for g, label in (("fit", "fit runs"), ("heldout", "held-out runs")):
        if not np.isfinite(c.rms_before_m[g]) and np.isfinite(c.rms_after_m[g]):
            lines.append(f"lag RMS on the {label}: {c.rms_after_m[g]:.3f} m calibrated (not re-simulated with the "
                         f"model as given); track RMS {c.track_rms_after_m[g]:.3f} m")
        elif np.isfinite(c.rms_before_m[g]):
            lines.append(f"lag RMS on the {label}: {c.rms_before_m[g]:.3f} m -> {c.rms_after_m[g]:.3f} m; "
                         f"track RMS {c.track_rms_before_m[g]:.3f} m -> {c.track_rms_after_m[g]:.3f} m")
    lines.append(f"took {c.timing_s['total']:.0f} s")
    return lines
