"""A report a person can look at: belt speeds and setpoints, fish along the line, outfeed gaps, KPIs.

Plots are PNG files (matplotlib, Agg backend: no display needed) embedded in one ``report.html``.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from plant.contract.kpis import singulation_table  # noqa: E402
from plant.contract.passages import belt_speed_fn, passages  # noqa: E402

from fishfmu.cosim.results import RunResult  # noqa: E402
from fishfmu.output.atomic import write_bytes_atomic, write_text_atomic  # noqa: E402


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def belt_figure(result: RunResult):
    fig, ax = plt.subplots(figsize=(8, 3.2))
    belts = result.run.belts
    for i, (cid, g) in enumerate(belts.groupby("conveyor_id", sort=False)):
        color = f"C{i}"
        ax.plot(g.t_s, g.speed_mps, color=color, label=f"{cid} speed")
        ax.plot(g.t_s, g.setpoint_mps, color=color, ls="--", lw=0.8, label=f"{cid} setpoint")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("belt speed [m/s]")
    ax.legend(ncol=4, fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    return fig


def fish_figure(result: RunResult):
    fig, ax = plt.subplots(figsize=(8, 4))
    tr = result.run.tracks
    for fid, g in tr.groupby("fish_id", sort=False):
        ax.plot(g.t_s, g.x_m, lw=0.9)
    for c in result.scenario.line.conveyors[1:]:
        ax.axhline(c.x_start_m, color="k", lw=0.5, alpha=0.4)
    for p in result.scenario.line.photoeyes:
        ax.axhline(p.x_m, color="r", lw=0.5, ls=":", alpha=0.6)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("fish mid-point x [m]")
    ax.set_title("fish along the line (grey: transfers, red dotted: photo-eyes)", fontsize=9)
    ax.grid(alpha=0.3)
    return fig


def gap_figure(result: RunResult):
    fig, ax = plt.subplots(figsize=(5, 3.2))
    sc = result.scenario
    try:
        p = passages(result.run, sc.line, sc.kpi)
        out_conv = sc.line.conveyor_at(sc.line.photoeye(sc.kpi.outfeed_photoeye).x_m).id
        table = singulation_table(p, belt_speed_fn(result.run, out_conv), sc.kpi.min_gap_m)
        gaps = table["gap_after_m"].dropna().to_numpy()
    except Exception:  # a report must not fail a run that produced data
        gaps = np.array([])
    if len(gaps):
        ax.hist(np.clip(gaps, -0.5, 3.0), bins=30, color="C0")
    ax.axvline(sc.kpi.min_gap_m, color="r", ls="--", label=f"min_gap_m = {sc.kpi.min_gap_m}")
    ax.set_xlabel("gap to the next fish at the outfeed [m] (clipped to [-0.5, 3])")
    ax.set_ylabel("count")
    ax.legend(fontsize=8)
    return fig


def write_report(result: RunResult, out: Path) -> Path:
    figures = {"belts.png": belt_figure(result), "fish_x.png": fish_figure(result), "outfeed_gaps.png": gap_figure(result)}
    blobs = {}
    for name, fig in figures.items():
        data = _png(fig)
        write_bytes_atomic(out / name, data)
        blobs[name] = base64.b64encode(data).decode()
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(_fmt(v))}</td></tr>"
                   for k, v in result.kpis.items() if not isinstance(v, dict))
    if result.scenario.line.devices:  # beside the singulation rate, what reaches the machine downstream (kpis.md)
        k = result.kpis
        out_n = k["singulated"] + k["doubles_out"]
        purity = k["singulated"] / out_n if out_n else None
        rows += (f"<tr><td>outfeed purity: singulated / (singulated + doubles_out)</td><td>{_fmt(purity)}</td></tr>"
                 + "".join(f"<tr><td>rejected by {html.escape(d)}</td><td>{n}</td></tr>"
                           for d, n in k.get("rejected_by", {}).items()))
    expect = "".join(f"<li class='{'ok' if e.ok else 'bad'}'>{html.escape(e.message)}</li>" for e in result.expect)
    status = html.escape(result.status + (f": {result.error}" if result.error else ""))
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(result.scenario.run.name)}</title>
<style>body{{font-family:sans-serif;max-width:960px;margin:2em auto}} td{{padding:2px 12px}}
.ok{{color:#060}} .bad{{color:#a00}} img{{max-width:100%}}</style></head><body>
<h1>{html.escape(result.scenario.run.name)}</h1>
<p>status: {status}; simulated {result.t_end_s:.2f} s in {result.wall_s:.1f} s wall; seed {result.scenario.run.seed}</p>
<h2>KPIs</h2><table>{rows}</table><ul>{expect}</ul>
<h2>Belt speeds and setpoints</h2><img src="data:image/png;base64,{blobs['belts.png']}">
<h2>Fish along the line</h2><img src="data:image/png;base64,{blobs['fish_x.png']}">
<h2>Gaps at the outfeed</h2><img src="data:image/png;base64,{blobs['outfeed_gaps.png']}">
</body></html>
"""
    path = out / "report.html"
    write_text_atomic(path, page)
    return path


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
