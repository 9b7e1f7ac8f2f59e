"""Writing a diagnosis: diagnosis.json, the fitted fragment, the candidates' tests, their signature plots, a report."""

from __future__ import annotations

import base64
import html
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from fishfmu.analysis.calibrate_report import calibration_document  # noqa: E402
from fishfmu.analysis.candidates import CANDIDATES  # noqa: E402
from fishfmu.analysis.diagnose import DECISION_RULE, MIN_GAIN, NOT_CONFIRMED, CandidateFit, Diagnosis  # noqa: E402
from fishfmu.analysis.scan import COVARIATES, QUANTITIES  # noqa: E402
from fishfmu.analysis.mismatch import take_up_text  # noqa: E402
from fishfmu.analysis.signatures import ALPHA, SUGGESTIVE, CovariateTest, significant  # noqa: E402
from fishfmu.output.atomic import json_safe, write_figure_atomic, write_json_atomic, write_text_atomic  # noqa: E402


def fit_text(f: CandidateFit) -> str:
    values = ", ".join(f"{k} = {v:.4g} [{f.ci95[k][0]:.4g}, {f.ci95[k][1]:.4g}]" if k in f.ci95 else f"{k} = {v:.4g}"
                       for k, v in f.values.items())
    gain = (f"On held-out runs the extended model removes {f.heldout_gain:.1%} of the error (95 % interval "
            f"{f.heldout_gain_ci95[0]:.1%} to {f.heldout_gain_ci95[1]:.1%}; RMS {f.heldout_rms_before:.4g} -> "
            f"{f.heldout_rms_after:.4g} {f.error_unit})")
    ends = "".join(f" {k} is the {v}: the data may want a value beyond it (at a physical bound: none of it)."
                   for k, v in f.at_grid_end.items())
    ends += "".join(f" The extended model at {why}: left out of the fit." for why in f.failed_values.values())
    if f.confirmed:
        return f"Fitted on the calibrated model: {values or 'no parameter'}.{ends} {gain}."
    return (f"{NOT_CONFIRMED[0].upper()}{NOT_CONFIRMED[1:]}: {gain}, less than {MIN_GAIN:.0%} with its interval above "
            f"zero, so the extension is no fix (fragment.toml carries it as comments only). As fitted: "
            f"{values or 'no parameter'}.{ends}")


def extension_text(d: Diagnosis) -> str:
    """One line on the named cause's extension: confirmed on held-out runs, not confirmed, or none."""
    if d.fit is None:
        return "none (no cause named)"
    lo, hi = d.fit.heldout_gain_ci95
    gain = f"held-out gain {d.fit.heldout_gain:.1%} [{lo:.1%}, {hi:.1%}]"
    if d.extension == "confirmed":
        return f"confirmed: {gain} (fragment.toml carries it)"
    return f"{d.cause} {NOT_CONFIRMED}: {gain} (fragment.toml: calibration only, the extension as comments)"


def decision_text(d: Diagnosis) -> str:
    """The answer in words: the causes named, or that the model fits these runs (and how well), or the unexplained
    discrepancy (where, what it follows, how large) -- never one for another."""
    j = d.judgement
    parts = []
    if d.causes:
        for name in d.causes:
            t = next(t for t in j.tests if t.candidate == name)
            f = next((f for f in d.fits if f.name == name), None)
            parts.append(f"{name}: {CANDIDATES[name].description}. Its signature: {t.quantity} follows {t.covariate} "
                         f"({t.shape}; p = {t.p_value:.3f}, held-out gain {t.heldout_gain:.1%} "
                         f"[{t.heldout_gain_ci95[0]:.1%}, {t.heldout_gain_ci95[1]:.1%}]).")
            if f is not None:
                parts.append(fit_text(f))
    for f in d.further:
        if f.name not in d.causes:
            parts.append(f"{f.name} is significant by its signature, but its extension does not beat the model "
                         f"extended with {', '.join(d.causes) or 'the causes before it'} on held-out runs (gain "
                         f"{f.heldout_gain:.1%} [{f.heldout_gain_ci95[0]:.1%}, {f.heldout_gain_ci95[1]:.1%}]): not named.")
    for name, why in d.rivals.items():
        parts.append(f"{name} is significant by its signature, but not named: {why}.")
    if d.unexplained:
        parts.append(("Beside the named causes, an" if d.causes else "No candidate explains the data, but an")
                     + " unexplained discrepancy: " + "; ".join(f.text for f in d.unexplained) + ".")
    if not d.causes and not d.unexplained:
        parts.append("The model fits these runs: no candidate's quantity follows its covariate clearly (p-value at "
                     f"most {ALPHA:g} and better than the constant on held-out runs), and nothing the data carry "
                     "follows any covariate beyond what the model predicts (the unexplained-discrepancy scan)."
                     + quality_text(d))
        parts.extend(f"Cannot decide {u}." for u in j.undecided)
    if d.scan is not None and d.scan.mismatch_findings:
        parts.append("The base model's own mismatch (how it responds to what it is given of each fish and run, its "
                     "size, heading and the belts' speeds; not a cause): " + "; ".join(f.text for f in d.scan.mismatch_findings) + ".")
    if take_up_text(d.take_up):
        parts.append(take_up_text(d.take_up))
    if d.judgement.left_out:
        parts.append(f"Left out (--without): {', '.join(d.judgement.left_out)}.")
    return " ".join(parts)


def quality_text(d: Diagnosis) -> str:
    q = d.quality
    if not q:
        return ""
    return (f" The lags of fish alone across transfers differ from the model by {100 * q['lag_rms_m']:.1f} cm RMS "
            f"beyond each transfer's constant, {q['ratio']:.1f} times what the tracker's own noise "
            f"({1e3 * q['tracker_noise_m']:.1f} mm) makes of a lag.")


def candidate_lines(d: Diagnosis) -> list[str]:
    """Every candidate's test, most certain first: p-value, held-out gain with interval, effect, shape."""
    ranked = sorted(d.judgement.tests, key=lambda t: (np.nan_to_num(t.p_value, nan=2.0), -t.heldout_gain_ci95[0]))
    lines = []
    for t in ranked:
        if not t.judged:
            lines.append(f"{t.candidate}: not judged ({t.note})")
            continue
        floor = f" (smallest worth naming {t.min_effect:.3g})" if t.min_effect else ""
        lines.append(f"{t.candidate}: p = {t.p_value:.3f}, held-out gain {t.heldout_gain:.1%} "
                     f"[{t.heldout_gain_ci95[0]:.1%}, {t.heldout_gain_ci95[1]:.1%}], effect {t.effect:.3g}{floor}; "
                     f"{t.shape}" + (" significant" if significant(t) else ""))
    return lines


def test_entry(t: CovariateTest) -> dict:
    return {"name": t.candidate, "quantity": t.quantity, "covariate": t.covariate, "judged": t.judged,
            "p_value": t.p_value, "heldout_gain": t.heldout_gain, "heldout_gain_ci95": list(t.heldout_gain_ci95),
            "explained": t.explained, "shape": t.shape, "slope": t.slope, "effect": t.effect,
            "min_effect": t.min_effect, "significant": significant(t), "rows": t.n_rows, "runs": t.n_runs,
            "gain_by_run": t.gain_by_run, "note": t.note}


def diagnosis_document(d: Diagnosis) -> dict:
    f = d.fit
    base_rms = [v for v in d.base_rms_m.values() if v == v]
    after_rms = [v for v in d.after_rms_m.values() if v == v]
    ranked = sorted(d.judgement.tests, key=lambda t: (np.nan_to_num(t.p_value, nan=2.0), -t.heldout_gain_ci95[0]))
    return {
        "answer": d.answer,
        "causes": d.causes,
        "cause": d.cause,
        "left_out": d.judgement.left_out,
        "unexplained": [x.as_dict() for x in d.unexplained],
        "not_named": {**{f.name: "extension not confirmed on top of the causes before it" for f in d.further
                         if f.name not in d.causes}, **d.rivals},
        "further": [{"name": f.name, "values": f.values, "ci95": {k: list(v) for k, v in f.ci95.items()},
                     "terms": d.further_terms.get(f.name, {}), "confirmed": f.confirmed, "heldout_gain": f.heldout_gain,
                     "heldout_gain_ci95": list(f.heldout_gain_ci95)} for f in d.further],
        "base_mismatch": {"transfers": d.mismatch, "take_up": d.take_up,
                          "dependences": [x.as_dict() for x in (d.scan.mismatch_findings if d.scan is not None else [])]},
        "fit_quality": d.quality,
        "scan": ({"threshold": d.scan.threshold, "tests": len(d.scan.tests), "results": d.scan.results()}
                 if d.scan is not None else None),
        "decision": decision_text(d),
        "undecided": d.judgement.undecided,
        "candidates": [test_entry(t) for t in ranked],
        "ranking": [t.candidate for t in ranked],
        "parameters": ({k: {"value": v, "ci95": list(f.ci95.get(k, (None, None))), "at_grid_end": f.at_grid_end.get(k)}
                        for k, v in f.values.items()} if f else {}),
        "failed_values": ({f"{v:g}": why for v, why in f.failed_values.items()} if f else {}),
        "terms": d.terms,
        "extension": {"status": d.extension, "applied": d.extension == "confirmed", "text": extension_text(d)},
        "heldout": ({"rms_before": f.heldout_rms_before, "rms_after": f.heldout_rms_after, "unit": f.error_unit,
                     "gain": f.heldout_gain, "gain_ci95": list(f.heldout_gain_ci95), "gain_by_run": f.gain_by_run,
                     "base_by_run": f.base_by_run,
                     **({"side_by_side": {**f.side_by_side.attrs, "runs": f.side_by_side.to_dict("records")}}
                        if f.side_by_side is not None else {})}
                    if f else {"gain": 0.0}),
        "track_rms_m": {"before": float(np.mean(base_rms)) if base_rms else None,
                        "after": float(np.mean(after_rms)) if after_rms else None,
                        "per_run_before": d.base_rms_m, "per_run_after": d.after_rms_m},
        "calibration": calibration_document(d.calibration, d.calibration.base) if d.calibration else None,
        "rules": {"alpha": ALPHA, "suggestive": SUGGESTIVE, "rule": DECISION_RULE, "fit_min_gain": MIN_GAIN},
        "run_levels": d.run_levels.to_dict(orient="records"),
        "drop_lags": d.drop_lags.to_dict(orient="records"),
        "timing_s": d.timing_s,
    }


def _img(fig, path: Path) -> str:
    try:
        data = write_figure_atomic(path, fig, dpi=100, bbox_inches="tight")
    finally:
        plt.close(fig)
    return base64.b64encode(data).decode()


def signature_figure(d: Diagnosis, out: Path) -> dict[str, str]:
    """One panel per candidate, three to a row: its quantity against its covariate, as its test reads them (its own
    ``plot``), titled with its p-value and whether it is significant; then the first unexplained finding's quantity
    against its covariate, and the answer."""
    rows = d.judgement.rows
    tests = {t.candidate: t for t in d.judgement.tests}
    names = [n for n, c in CANDIDATES.items() if c.plot is not None]
    n_rows = -(-(len(names) + 2) // 3)
    fig, grid = plt.subplots(n_rows, 3, figsize=(14, 4.2 * n_rows), layout="constrained")
    axes = grid.ravel()
    for ax, name in zip(axes, names):
        CANDIDATES[name].plot(ax, rows)
        t = tests.get(name)
        verdict = ("left out" if name in d.judgement.left_out else "not judged" if t is None or not t.judged else
                   f"p = {t.p_value:.3f}, held-out gain {t.heldout_gain:.0%}" + (" - significant" if significant(t) else ""))
        ax.set_title(f"{name}\n{verdict}", fontsize=10, fontweight="bold" if name in d.causes else "normal")
    ax = axes[len(names)]
    f = d.unexplained[0] if d.unexplained else None
    table = d.scan.tables.get(f.table) if f is not None and d.scan is not None else None
    model = d.scan.tables.get(f.model_table) if f is not None and f.model_table else None
    if f is not None and table is not None:
        q = next(q for q in QUANTITIES if q.table == f.table and q.model_table == f.model_table)
        flag = COVARIATES[f.covariate_key].column
        if model is not None:  # the rows where the covariate holds, measured against modelled
            ax.boxplot([t.loc[t[flag] == 1.0, q.column].to_numpy(float) for t in (table, model)],
                       tick_labels=["measured", "model"])
            ax.set(ylabel=f"{q.column} of the rows where {flag} = 1")
        else:
            for place, g in table.groupby(q.location_column):
                ax.plot(g[flag], g[q.column], ".", alpha=0.4, label=str(place))
            ax.legend(fontsize=7)
            ax.set(xlabel=f.covariate, ylabel=f"{f.quantity} [{f.unit}]" if f.unit else f.quantity)
        ax.set_title(f"unexplained: at {f.location_kind} {f.location_id}\np = {f.test.p_value:.4f}, held-out gain "
                     f"{f.test.heldout_gain:.0%}", fontsize=10, fontweight="bold")
    else:
        ax.axis("off")
        ax.text(0.0, 0.95, "nothing unexplained", va="top", fontsize=11)
    for ax in axes[len(names) + 1:]:
        ax.axis("off")
    axes[len(names) + 1].text(0.0, 0.95, f"answer: {d.answer}\ncause: {d.cause}\nextension: {d.extension}", va="top",
                              fontsize=11, wrap=True)
    return {"signatures.png": _img(fig, out / "signatures.png")}


def fit_figures(d: Diagnosis, out: Path) -> dict[str, str]:
    figs = {}
    if len(d.run_levels):
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
        lv = d.run_levels.sort_values("hours_post_mortem")
        axes[0].plot(lv["hours_post_mortem"], lv["friction_level"], "o-")
        axes[0].set_ylabel("the run's best friction level [x]")
        axes[1].plot(lv["hours_post_mortem"], lv["rigor_level"], "o-")
        axes[1].set_ylabel("the run's best rigor level [x soft stiffness]")
        for ax in axes:
            ax.set_xlabel("hours post mortem")
        figs["run_levels.png"] = _img(fig, out / "run_levels.png")
    for f in d.fits:
        if f.grid is None:
            continue
        fig, ax = plt.subplots(figsize=(4.5, 3))
        draw_fit_curve(ax, f)
        figs[f"fit_{f.name}.png"] = _img(fig, out / f"fit_{f.name}.png")
    for f in d.fits:
        if f.base_by_run:
            figs[f"heldout_{f.name}.png"] = heldout_figure(f, d.extension, out / f"heldout_{f.name}.png")
        if f.side_by_side is not None and len(f.side_by_side):
            figs[f"side_by_side_{f.name}.png"] = side_by_side_figure(f, out / f"side_by_side_{f.name}.png")
    return figs


def draw_fit_curve(ax, f: CandidateFit) -> None:
    """A grid-fitted candidate's error against its strength, in the unit it is scored in, with the value fitted and
    the strengths that failed to simulate (left out of the fit) marked where they lie."""
    g = f.grid.groupby("value").agg(ss=("ss", "sum"), n=("n", "sum"))
    rms = np.sqrt(g["ss"] / g["n"].clip(lower=1))
    ax.plot(g.index, rms, "o-", label="simulated on every run")
    for value in f.values.values():
        ax.axvline(value, ls="--", c="0.5", label=f"fitted: {value:.3g}")
    if f.failed_values:
        ax.plot(list(f.failed_values), [float(rms.max())] * len(f.failed_values), "x", c="C3", ms=8,
                label="failed to simulate (left out)")
    ax.set_xlabel(f"{f.name} strength [{CANDIDATES[f.name].unit}]")
    ax.set_ylabel(f"RMS residual [{f.error_unit}]")
    ax.legend(fontsize=7)


def side_by_side_figure(f: CandidateFit, path: Path) -> str:
    """The held-out runs in the quantity the candidate's test reads, against its covariate: measured, the base
    model and the extended one (each run predicted with what was chosen on the others)."""
    t = f.side_by_side
    fig, ax = plt.subplots(figsize=(5.5, 3.6), layout="constrained")
    ax.plot(t["covariate"], t["measured"], "ko", label="measured")
    ax.plot(t["covariate"], t["base"], "s", color="0.6", label="base (calibrated)")
    ax.plot(t["covariate"], t["extended"], "^", color="tab:blue", label=f"extended with {f.name}")
    ax.set(xlabel=t.attrs.get("covariate", "covariate"), ylabel=textwrap.fill(t.attrs.get("quantity", "quantity"), 36))
    if (t["covariate"] > 0).all() and t["covariate"].max() > 10 * t["covariate"].min():
        ax.set_xscale("log")
    ax.set_title(f"each run held out: {f.name}", fontsize=10)
    fig.legend(loc="outside lower center", ncols=3, fontsize=8)
    return _img(fig, path)


def heldout_figure(f: CandidateFit, status: str, path: Path) -> str:
    """Each run held out: its error with the base model and with the extended one (chosen on the other runs), side
    by side, as RMS per row where the rows are counted, else the root of the run's error."""
    runs = sorted(f.base_by_run)
    before = np.sqrt(np.maximum([f.base_by_run[r] for r in runs], 0.0))
    after = np.sqrt(np.maximum([f.base_by_run[r] - f.gain_by_run.get(r, 0.0) for r in runs], 0.0))
    fig, ax = plt.subplots(figsize=(max(5.0, 0.6 * len(runs) + 2.5), 3.6), layout="constrained")
    x = np.arange(len(runs))
    ax.bar(x - 0.2, before, 0.4, label="base (calibrated)", color="0.6")
    ax.bar(x + 0.2, after, 0.4, label=f"extended with {f.name}", color="tab:blue")
    ax.set_xticks(x, runs, rotation=45 if len(runs) > 8 else 0)
    ax.set_ylabel(f"held-out error, root of the run's\nsum of squares [{f.error_unit.split(' (')[0]}]")
    ax.set_title(f"each run held out: {f.name} extension {status}, gain {f.heldout_gain:.0%} "
                 f"[{f.heldout_gain_ci95[0]:.0%}, {f.heldout_gain_ci95[1]:.0%}]", fontsize=10)
    fig.legend(loc="outside lower center", ncols=2, fontsize=8)
    return _img(fig, path)


def write_diagnosis(d: Diagnosis, out: Path) -> dict[str, Path]:
    doc = diagnosis_document(d)
    paths = {"json": out / "diagnosis.json", "fragment": out / "fragment.toml", "tests": out / "tests.csv",
             "report": out / "report.html"}
    write_text_atomic(paths["fragment"], d.fragment)
    table = pd.DataFrame([{k: v for k, v in test_entry(t).items() if k != "gain_by_run"} for t in d.judgement.tests])
    write_text_atomic(paths["tests"], table.to_csv(index=False, float_format="%.6g"))
    grids = [f.grid.assign(candidate=f.name) for f in d.fits if f.grid is not None]
    if grids:
        paths["grid"] = out / "fit_grid.csv"
        write_text_atomic(paths["grid"], pd.concat(grids).to_csv(index=False, float_format="%.6g"))
    figs = {**signature_figure(d, out), **fit_figures(d, out)}
    rows = "".join(
        f"<tr><td>{html.escape(c['name'])}</td><td>{html.escape(c['quantity'])}</td>"
        f"<td>{html.escape(c['covariate'])}</td><td>{c['p_value']:.3f}</td>"
        f"<td>{c['heldout_gain']:.1%} [{c['heldout_gain_ci95'][0]:.1%}, {c['heldout_gain_ci95'][1]:.1%}]</td>"
        f"<td>{'yes' if c['significant'] else 'no'}</td><td>{html.escape(c['note'])}</td></tr>"
        for c in doc["candidates"])
    imgs = "".join(f'<img src="data:image/png;base64,{b}">' for b in figs.values())
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto}} img{{max-width:100%}} td,th{{padding:2px 10px}}</style>
</head><body><h1>Diagnosis: {html.escape(d.cause)}</h1><p>{html.escape(doc['decision'])}</p>
<h2>Candidates</h2><table><tr><th>candidate</th><th>quantity</th><th>covariate</th><th>p</th>
<th>held-out gain [95 %]</th><th>significant</th><th>note</th></tr>
{rows}</table><p>{html.escape(DECISION_RULE)}</p><h2>Fragment</h2><pre>{html.escape(d.fragment)}</pre>
<h2>Signatures and fits</h2>{imgs}
<p>Timing: {', '.join(f'{k} {v:.0f} s' for k, v in d.timing_s.items())}</p></body></html>
"""
    write_text_atomic(paths["report"], page)
    write_json_atomic(paths["json"], json_safe(doc))
    return paths
