"""What a person looks at after a sweep: plots of each KPI against each swept parameter with its
confidence band, and the summary as a console table."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import pandas as pd
from rich.console import Console
from rich.table import Table

from plant.contract.kpis import kpi_keys

from fishfmu.output.atomic import write_figure_atomic
from fishfmu.output.manifest import note_dir
from fishfmu.terminal import labelled

PLOT_KPIS = kpi_keys("singulation_rate", "throughput_time_s", "fpm_in", "fpm_out", "singulated", "lost",
                     "gap_min_m", "gap_p10_m", "gap_median_m")
"""the headline rates and times first (names checked against :data:`plant.contract.kpis.KPI_KEYS`)"""
TABLE_KPIS = kpi_keys("singulation_rate", "throughput_time_s", "fpm_out")
MAX_LEGEND = 8


def _number(v: Any) -> float | None:
    if v is None or isinstance(v, bool):
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(x) else x


def _label(row: pd.Series, keys: list[str]) -> str:
    return ", ".join(f"{k.rsplit('.', 1)[-1]}={row[k]}" for k in keys)


def write_plots(summary: pd.DataFrame, parameters: list[str], folder: Path) -> Path:
    """One PNG per KPI and swept parameter: the mean over seeds with its 95 % band (Student t), one
    line per combination of the other parameters.  Parameters with a single value get no plot; the
    singulation rate's band is drawn clipped to [0, 1] (the tables keep the unclipped interval)."""
    # slow and optional: matplotlib, only when plots are asked for (Figure, no pyplot: no global state, Agg canvas)
    from matplotlib.figure import Figure
    folder.mkdir(parents=True, exist_ok=True)
    note_dir(folder)
    for x_key in parameters:
        if x_key not in summary or summary[x_key].nunique(dropna=False) < 2:
            continue
        others = [k for k in parameters if k != x_key]
        numeric = all(_number(v) is not None for v in summary[x_key])
        categories = list(dict.fromkeys(summary[x_key]))
        groups = summary.groupby(others, sort=False, dropna=False) if others else [((), summary)]
        for kpi in PLOT_KPIS:
            if f"{kpi}_mean" not in summary:
                continue
            fig = Figure(figsize=(6.4, 4.2), dpi=110)
            ax = fig.add_subplot()
            n_lines = 0
            for _, g in groups:
                g = g[[_number(v) is not None for v in g[f"{kpi}_mean"]]]
                if g.empty:
                    continue
                xs = [float(v) for v in g[x_key]] if numeric else [categories.index(v) for v in g[x_key]]
                order = sorted(range(len(xs)), key=xs.__getitem__)
                xs = [xs[i] for i in order]
                g = g.iloc[order]
                line, = ax.plot(xs, g[f"{kpi}_mean"].astype(float), marker="o",
                                label=_label(g.iloc[0], others) if others else None)
                lo, hi = g[f"{kpi}_ci_low"].astype(float), g[f"{kpi}_ci_high"].astype(float)
                if kpi == "singulation_rate":  # the t band of a proportion may pass 0 or 1; draw it inside
                    lo, hi = lo.clip(lower=0.0), hi.clip(upper=1.0)
                has_band = [_number(a) is not None and _number(b) is not None for a, b in zip(lo, hi)]
                if any(has_band):
                    ax.fill_between([x for x, b in zip(xs, has_band) if b], lo[has_band].astype(float),
                                    hi[has_band].astype(float), color=line.get_color(), alpha=0.2, linewidth=0)
                n_lines += 1
            if n_lines == 0:
                continue
            if not numeric:
                ax.set_xticks(range(len(categories)), [str(c) for c in categories])
            ax.set_xlabel(x_key)
            ax.set_ylabel(kpi)
            ax.set_title(f"{kpi}: mean and 95 % CI over seeds", fontsize=10)
            ax.grid(alpha=0.3)
            if others and 1 < n_lines <= MAX_LEGEND:
                ax.legend(fontsize=7)
            fig.tight_layout()
            png = folder / f"{kpi}__{re.sub(r'[^A-Za-z0-9_]+', '_', x_key).strip('_')}.png"
            write_figure_atomic(png, fig)  # a new file, renamed over the old: a link to the old keeps it
    return folder


def _fmt(v: Any, digits: int = 3) -> str:
    x = _number(v)
    return "-" if x is None else f"{x:.{digits}g}"


def mean_ci_text(row: pd.Series, kpi: str) -> str:
    mean, lo, hi = row.get(f"{kpi}_mean"), row.get(f"{kpi}_ci_low"), row.get(f"{kpi}_ci_high")
    if _number(mean) is None:
        return "-"
    return f"{_fmt(mean)} [{_fmt(lo)}, {_fmt(hi)}]" if _number(lo) is not None else _fmt(mean)


def print_summary(summary: pd.DataFrame, parameters: list[str], console: Console, title: str = "sweep") -> None:
    """One line per point: its parameters, runs that succeeded, and the main KPIs as mean [95 % CI]."""
    table = Table(title=f"{title}: mean [95 % CI] over seeds")
    for k in parameters:
        table.add_column(k.rsplit(".", 1)[-1] if len(k) > 24 else k, justify="right")
    table.add_column("ok/runs", justify="right")
    for k in TABLE_KPIS:
        table.add_column(k, justify="right")
    for _, row in summary.iterrows():
        table.add_row(*[str(row[k]) for k in parameters], f"{row['n_ok']}/{row['n_runs']}",
                      *[mean_ci_text(row, k) for k in TABLE_KPIS])
    console.print(table)
    failed = summary[summary["n_failed"] > 0]
    for _, row in failed.iterrows():
        where = ", ".join(f"{k}={row[k]}" for k in parameters) or "scenario"
        console.print(labelled("failed", f"{where}: {row['n_failed']} of {row['n_runs']} runs: {row['errors']}", "red"))


def print_statistics(row: pd.Series, kpis: tuple[str, ...], console: Console, title: str) -> None:
    """The statistics of one point (``fishfmu run --seeds``): each KPI's mean, CI, sd and count."""
    table = Table(title=title)
    for c in ("KPI", "mean", "95 % CI (t)", "sd", "n"):
        table.add_column(c, justify="left" if c == "KPI" else "right")
    for k in kpis:
        n, undefined = row.get(f"{k}_n"), row.get(f"{k}_n_undefined")
        ci = f"[{_fmt(row.get(f'{k}_ci_low'), 4)}, {_fmt(row.get(f'{k}_ci_high'), 4)}]"
        table.add_row(k, _fmt(row.get(f"{k}_mean"), 4), ci, _fmt(row.get(f"{k}_sd"), 3),
                      f"{n}" + (f" ({undefined} undefined)" if undefined else ""))
    console.print(table)
    if _number(row.get("singulation_rate_pooled")) is not None:
        console.print(f"singulation rate pooled over all fish: {row['singulation_rate_pooled']:.3f}, Wilson 95 % "
                      f"[{row['singulation_rate_wilson_low']:.3f}, {row['singulation_rate_wilson_high']:.3f}] "
                      "(treats every fish as an independent trial; the t interval treats batches as the samples)", highlight=False)
