"""Writing a diagnosis: diagnosis.json, the fitted fragment, evidence tables, plots, a report."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from fishfmu.analysis.candidates import CANDIDATES  # noqa: E402
from fishfmu.analysis.calibrate import calibration_document  # noqa: E402
from fishfmu.analysis.diagnose import DECISION_RULE, MIN_GAIN, Diagnosis  # noqa: E402
from fishfmu.analysis.evidence_base import RunLevelShape  # noqa: E402
from fishfmu.analysis.evidence_base import SUPPORT_Z  # noqa: E402
from fishfmu.analysis.residuals import BELT_RESIDUAL_DTYPES, PAIR_RESIDUAL_DTYPES, alone, concat_typed  # noqa: E402


def decision_text(d: Diagnosis) -> str:
    if d.cause == "none":
        fitted = [f for f in d.fits]
        return ("No fitted candidate removed at least {:.0%} of the held-out error with a 95 % interval above zero: "
                "no significant discrepancy was found ({}).".format(MIN_GAIN, "; ".join(
                    f"{f.name}: gain {f.heldout_gain:.1%} [{f.heldout_gain_ci95[0]:.1%}, {f.heldout_gain_ci95[1]:.1%}]"
                    for f in fitted))) + "".join(f" {line}" for line in undecided_lines(d))
    w = next(f for f in d.fits if f.name == d.cause)
    values = ", ".join(f"{k} = {v:.4g} [{w.ci95[k][0]:.4g}, {w.ci95[k][1]:.4g}]" for k, v in w.values.items())
    return (f"{d.cause}: {CANDIDATES[d.cause].description}. Fitted {values}. On held-out runs it removes "
            f"{w.heldout_gain:.1%} of the error (95 % interval {w.heldout_gain_ci95[0]:.1%} to "
            f"{w.heldout_gain_ci95[1]:.1%}): RMS {w.heldout_rms_before:.4g} -> {w.heldout_rms_after:.4g} {w.error_unit}.")


def undecided_lines(d: Diagnosis) -> list[str]:
    """Candidates with a gain that one run carries: what more data would decide."""
    hours = dict(zip(d.run_levels["run_id"], d.run_levels["hours_post_mortem"])) if len(d.run_levels) else {}
    lines = []
    for f in d.fits:
        one = f.carried_by() if not f.significant else None
        if one:
            at = f" ({hours[one[0]]:g} h post mortem)" if one[0] in hours else ""
            lines.append(f"{f.name}'s gain comes {one[1]:.0%} from run {one[0]}{at}: one run cannot establish it, "
                         "more runs like it would decide.")
    return lines


def candidate_lines(d: Diagnosis) -> list[str]:
    """Every fitted candidate, ranked: its held-out gain with interval, its values, and its cheap evidence."""
    fits = {f.name: f for f in d.fits}
    lines = []
    for name in d.ranking():
        f = fits.get(name)
        if f is None:
            continue
        values = ", ".join(f"{k} {v:.3g}" for k, v in f.values.items())
        lines.append(f"{name}: held-out gain {f.heldout_gain:.1%} [{f.heldout_gain_ci95[0]:.1%}, "
                     f"{f.heldout_gain_ci95[1]:.1%}]{' significant' if f.significant else ''}; {values}; "
                     f"evidence z {f.evidence_z:.1f}")
    return lines


def diagnosis_document(d: Diagnosis) -> dict:
    ev = d.evidence.set_index("candidate")
    fits = {f.name: f for f in d.fits}
    candidates = []
    for name in d.ranking():
        f = fits.get(name)
        entry = {"name": name, "evidence_z": float(ev.loc[name, "evidence"]), "supported": bool(ev.loc[name, "supported"]),
                 "fitted": f is not None}
        if f is not None:
            entry.update({
                "parameters": {k: {"value": v, "ci95": list(f.ci95.get(k, (None, None)))} for k, v in f.values.items()},
                "heldout_gain": f.heldout_gain, "heldout_gain_ci95": list(f.heldout_gain_ci95),
                "heldout_rms_before": f.heldout_rms_before, "heldout_rms_after": f.heldout_rms_after,
                "error_unit": f.error_unit, "significant": f.significant, "gain_by_run": f.gain_by_run})
        candidates.append(entry)
    winner = fits.get(d.cause)
    base_rms = [v for v in d.base_rms_m.values() if v == v]
    after_rms = [v for v in d.after_rms_m.values() if v == v]
    return {
        "cause": d.cause,
        "decision": decision_text(d),
        "parameters": ({k: {"value": v, "ci95": list(winner.ci95.get(k, (None, None)))} for k, v in winner.values.items()}
                       if winner else {}),
        "heldout": ({"rms_before": winner.heldout_rms_before, "rms_after": winner.heldout_rms_after,
                     "unit": winner.error_unit, "gain": winner.heldout_gain, "gain_ci95": list(winner.heldout_gain_ci95)}
                    if winner else {"gain": 0.0}),
        "track_rms_m": {"before": float(np.mean(base_rms)) if base_rms else None,
                        "after": float(np.mean(after_rms)) if after_rms else None,
                        "per_run_before": d.base_rms_m, "per_run_after": d.after_rms_m},
        "ranking": d.ranking(),
        "calibration": calibration_document(d.calibration, d.calibration.base) if d.calibration else None,
        "candidates": candidates,
        "rules": {"min_gain": MIN_GAIN, "rule": DECISION_RULE, "evidence_support_z": SUPPORT_Z},
        "run_levels": d.run_levels.to_dict(orient="records"),
        "drop_lags": d.drop_lags.to_dict(orient="records"),
        "timing_s": d.timing_s,
    }


def _img(fig, path: Path) -> str:
    from fishfmu.output.atomic import write_figure_atomic
    try:
        data = write_figure_atomic(path, fig, dpi=100, bbox_inches="tight")
    finally:
        plt.close(fig)
    return base64.b64encode(data).decode()


def evidence_figures(d: Diagnosis, out: Path) -> dict[str, str]:
    rows = concat_typed([b.rows for b in d.baseline], BELT_RESIDUAL_DTYPES)
    free = alone(rows)
    figs = {}
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.3))
    if len(free):
        axes[0].plot(free["heading"], free["lag_m"], ".", ms=3, alpha=0.6)
        means = free.groupby("run_id").agg(lag=("lag_m", "mean"), h=("hours_post_mortem", "mean"))
        axes[1].plot(means["h"], means["lag"], "o")
        hh = np.linspace(0, max(float(means["h"].max()), 1.0), 100)
        ax2 = axes[1].twinx()
        shapes = [c.evidence for c in CANDIDATES.values() if isinstance(c.evidence, RunLevelShape) and c.evidence.label]
        for k, shape in enumerate(shapes):  # what the runs' mean lags are tested against
            ax2.plot(hh, shape.shape(hh), f"C{k + 1}", ls=("--", ":", "-.")[k % 3], lw=0.8, label=shape.label)
        ax2.legend(fontsize=7, loc="upper right")
    axes[0].set_xlabel("heading (cos yaw: +1 head first, -1 tail first)")
    axes[0].set_ylabel("lag on a belt, simulated - measured [m]")
    axes[1].set_xlabel("hours post mortem")
    axes[1].set_ylabel("mean lag of the run [m]")
    figs["evidence_friction.png"] = _img(fig, out / "evidence_friction.png")
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    pairs = concat_typed([b.pairs for b in d.baseline], PAIR_RESIDUAL_DTYPES)
    if len(pairs):
        axes[0].hist(pairs["dsep_m"].astype(float), bins=20)
    axes[0].set_xlabel("extra separation of close pairs, simulated - measured [m]")
    if len(d.drive):
        axes[1].plot(d.drive["load_force_n"], d.drive["residual_mps"], ",", alpha=0.5)
    axes[1].set_xlabel("belt load [N]")
    axes[1].set_ylabel("logged - model belt speed [m/s]")
    figs["evidence_pairs_drive.png"] = _img(fig, out / "evidence_pairs_drive.png")
    if len(d.run_levels):
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
        lv = d.run_levels.sort_values("hours_post_mortem")
        axes[0].plot(lv["hours_post_mortem"], lv["friction_level"], "o-")
        axes[0].set_ylabel("the run's best friction level [x]")
        axes[1].plot(lv["hours_post_mortem"], lv["rigor_level"], "o-")
        axes[1].set_ylabel("the run's best rigor level [x soft stiffness]")
        for ax in axes:
            ax.set_xlabel("hours post mortem")
        figs["signature_levels.png"] = _img(fig, out / "signature_levels.png")
    for f in d.fits:
        if f.grid is None:
            continue
        g = f.grid.groupby("value").agg(ss=("ss", "sum"), n=("n", "sum"))
        fig, ax = plt.subplots(figsize=(4.5, 3))
        ax.plot(g.index, np.sqrt(g["ss"] / g["n"].clip(lower=1)), "o-")
        ax.set_xlabel(f"{f.name} strength [{CANDIDATES[f.name].unit}]")
        ax.set_ylabel("RMS residual [m]")
        figs[f"fit_{f.name}.png"] = _img(fig, out / f"fit_{f.name}.png")
    return figs


def write_diagnosis(d: Diagnosis, out: Path) -> dict[str, Path]:
    from fishfmu.output.atomic import json_safe, write_json_atomic, write_text_atomic
    doc = diagnosis_document(d)
    paths = {"json": out / "diagnosis.json", "fragment": out / "fragment.toml", "evidence": out / "evidence.csv",
             "report": out / "report.html"}
    write_text_atomic(paths["fragment"], d.fragment)
    write_text_atomic(paths["evidence"], d.evidence.to_csv(index=False, float_format="%.6g"))
    grids = [f.grid.assign(candidate=f.name) for f in d.fits if f.grid is not None]
    if grids:
        paths["grid"] = out / "fit_grid.csv"
        write_text_atomic(paths["grid"], pd.concat(grids).to_csv(index=False, float_format="%.6g"))
    figs = evidence_figures(d, out)
    rank_rows = "".join(
        f"<tr><td>{c['name']}</td><td>{c['evidence_z']:.2f}</td><td>{'yes' if c['fitted'] else 'no'}</td>"
        f"<td>{(format(c['heldout_gain'], '.1%') + ' [' + format(c['heldout_gain_ci95'][0], '.1%') + ', ' + format(c['heldout_gain_ci95'][1], '.1%') + ']') if c['fitted'] else ''}</td></tr>"
        for c in doc["candidates"])
    imgs = "".join(f'<img src="data:image/png;base64,{b}">' for b in figs.values())
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:2em auto}} img{{max-width:100%}} td,th{{padding:2px 10px}}</style>
</head><body><h1>Diagnosis: {html.escape(d.cause)}</h1><p>{html.escape(doc['decision'])}</p>
<h2>Candidates</h2><table><tr><th>candidate</th><th>evidence |z|</th><th>fitted</th><th>held-out gain [95 %]</th></tr>
{rank_rows}</table><h2>Fragment</h2><pre>{html.escape(d.fragment)}</pre><h2>Evidence and fits</h2>{imgs}
<p>Timing: {', '.join(f'{k} {v:.0f} s' for k, v in d.timing_s.items())}</p></body></html>
"""
    write_text_atomic(paths["report"], page)
    write_json_atomic(paths["json"], json_safe(doc))
    return paths
