"""Plots a person would read for ``fishfmu compare``, in one HTML page."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from fishfmu.output.atomic import write_figure_atomic, write_text_atomic  # noqa: E402


def _save(fig, path: Path) -> str:
    try:
        data = write_figure_atomic(path, fig, dpi=100, bbox_inches="tight")
    finally:
        plt.close(fig)
    return base64.b64encode(data).decode()


def tracks_figure(c, run_index: int):
    """x(t) of every fish: measured (dots) and simulated (lines), same colour per fish."""
    run, res = c.dataset.runs[run_index], c.resims[run_index]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for i, (fid, m) in enumerate(run.tracks.groupby("fish_id", sort=False)):
        color = f"C{i % 10}"
        ax.plot(m["t_s"], m["x_m"], ".", ms=1.5, color=color)
        s = res.sim.tracks[res.sim.tracks["fish_id"] == fid]
        ax.plot(s["t_s"], s["x_m"], "-", lw=0.8, color=color)
    for conv in c.dataset.line.conveyors[1:]:
        ax.axhline(conv.x_start_m, color="k", lw=0.4, alpha=0.4)
    ax.set_title(f"run {run.id}: measured (dots) and simulated (lines)", fontsize=9)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("x [m]")
    return fig


def arrivals_figure(c):
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    a = c.arrivals.dropna(subset=["measured_t_s", "simulated_t_s"])
    for i, (sid, g) in enumerate(a.groupby("sensor_id")):
        ax.plot(g["measured_t_s"], g["simulated_t_s"], ".", ms=3, label=sid, color=f"C{i}")
    lim = [0, float(max(a["measured_t_s"].max(), a["simulated_t_s"].max())) if len(a) else 1.0]
    ax.plot(lim, lim, "k-", lw=0.6)
    ax.set_xlabel("measured arrival [s]")
    ax.set_ylabel("simulated arrival [s]")
    if len(a):  # no arrival on either side: nothing to name
        ax.legend(fontsize=7)
    return fig


def track_error_figure(c):
    fig, ax = plt.subplots(figsize=(6, 3.2))
    t = c.track.dropna(subset=["since_drop_s"])
    if len(t):
        bins = np.arange(0, float(t["since_drop_s"].max()) + 1.0, 1.0)
        g = t.groupby(pd.cut(t["since_drop_s"], bins), observed=True)["ex_m"]
        mid = [iv.mid for iv in g.median().index]
        ax.plot(mid, g.median().to_numpy(), "-", label="median")
        ax.fill_between(mid, g.quantile(0.1).to_numpy(), g.quantile(0.9).to_numpy(), alpha=0.3, label="10-90 %")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("time since drop [s]")
    ax.set_ylabel("simulated - measured x [m]")
    ax.legend(fontsize=7)
    return fig


def kpi_figure(c):
    fig, axes = plt.subplots(1, 2, figsize=(8, 3))
    for ax, k in zip(axes, ("singulation_rate", "throughput_time_s")):
        d = c.kpis[c.kpis["kpi"] == k]
        x = np.arange(len(d))
        ax.bar(x - 0.2, d["measured"].astype(float), 0.4, label="measured")
        ax.bar(x + 0.2, d["simulated"].astype(float), 0.4, label="simulated")
        ax.set_xticks(x, d["run_id"], rotation=90, fontsize=7)
        ax.set_title(k, fontsize=9)
    axes[0].legend(fontsize=7)
    return fig


def belt_figure(c):
    fig, ax = plt.subplots(figsize=(5, 3.2))
    b = c.belts.dropna(subset=["measured_mps", "model_mps"])
    if "load_force_n" in b:
        ax.plot(b["load_force_n"], b["measured_mps"] - b["model_mps"], ",", alpha=0.4)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("belt load [N]")
    ax.set_ylabel("logged - drive model speed [m/s]")
    return fig


def replay_links(replays: dict[str, Path], out: Path) -> str:
    """A list of the runs' replay pages, as links relative to the report (the folder can be moved)."""
    if not replays:
        return ""
    items = []
    for run_id, page in replays.items():
        href = page.relative_to(out).as_posix() if page.is_relative_to(out) else page.as_uri()
        size_mb = page.stat().st_size / 1e6 if page.exists() else float("nan")
        items.append(f'<li><a href="{html.escape(href)}">run {html.escape(run_id)}</a> ({size_mb:.2f} MB)</li>')
    return ("<h2>3D replays</h2><p>Each run in 3D in the browser (WebGL2, works offline): the simulated fish, "
            "and the measured ones as pale ghosts of the same colour at their tracked positions; the buttons "
            "<i>simulated / measured / both</i> (key <kbd>m</kbd>) choose what is drawn. A lamp on each "
            f"photo-eye shows the measured beam.</p><ul class=\"replays\">{''.join(items)}</ul>")


def _run_figure(run_id: str, blob: str, page: Path | None, out: Path) -> str:
    img = f'<img src="data:image/png;base64,{blob}" alt="tracks of run {html.escape(run_id)}">'
    if page is None or not page.is_relative_to(out):
        return img
    return f'<a href="{html.escape(page.relative_to(out).as_posix())}" title="3D replay of run {html.escape(run_id)}">{img}</a>'


def not_replayed_note(c) -> str:
    """What the comparison leaves out because a run's devices could not be replayed (empty when none)."""
    if not c.not_replayed:
        return ""
    items = "".join(f"<li>{html.escape(why)}</li>" for why in c.not_replayed.values())
    return ("<h2>Not replayed: devices without a command log</h2><p>These runs' re-simulations kept the line's devices "
            "home; the KPIs the devices change, and arrivals and tracks from the first device on, are left out "
            "(kpis.csv: <i>not compared</i>), not reported as model error. Log the devices' commands "
            f"(device_commands.csv) to compare them.</p><ul>{items}</ul>")


def write_compare_report(c, out: Path, replays: dict[str, Path] | None = None) -> Path:
    """The report page; ``replays``: run id -> that run's 3D replay page, linked from the report."""
    figs = {"arrivals.png": arrivals_figure(c), "track_error.png": track_error_figure(c), "kpis.png": kpi_figure(c),
            "belt_speed_error.png": belt_figure(c)}
    blobs = {name: _save(f, out / name) for name, f in figs.items()}
    run_blobs = []
    for i, run in enumerate(c.dataset.runs):
        if not c.resims[i].error:
            run_blobs.append((run.id, _save(tracks_figure(c, i), out / f"tracks_{run.id}.png")))
    summary = c.summary().round(4).to_html(index=False)
    kpis = c.kpis.pivot_table(index="run_id", columns="kpi", values=["measured", "simulated"], aggfunc="first")
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>compare {html.escape(c.dataset.name)}</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:2em auto}} img{{max-width:100%}} table{{font-size:12px}}
ul.replays{{columns:4}}</style>
</head><body><h1>{html.escape(c.dataset.name)}: measured and simulated</h1>
{replay_links(replays or {}, out)}
{not_replayed_note(c)}
<h2>Error measures across runs</h2>{summary}
<h2>KPIs per run</h2><img src="data:image/png;base64,{blobs['kpis.png']}">{kpis.round(3).to_html()}
<h2>Arrivals at the photo-eyes</h2><img src="data:image/png;base64,{blobs['arrivals.png']}">
<h2>Track error against time since the drop</h2><img src="data:image/png;base64,{blobs['track_error.png']}">
<h2>Belt speeds: logged against the drive model</h2><img src="data:image/png;base64,{blobs['belt_speed_error.png']}">
<h2>Runs</h2>{''.join(_run_figure(rid, b, (replays or {}).get(rid), out) for rid, b in run_blobs)}
</body></html>
"""
    path = out / "report.html"
    write_text_atomic(path, page)
    return path
