"""The paper's test as a study: singulation over the two unknowns that set the throughput time.

Reads the summary of a two-parameter ``fishfmu sweep`` (feed interval x belt speed scale, see README
"The paper's test as a study") and draws the mean singulation rate over the grid with the contour of
the paper's measured throughput time (45 s) and of the paper's singulation (56 %), and prints, for each
belt speed scale, the feed on the 45 s line and the singulation there (linear between the two grid points
around it, with their 95 % intervals interpolated the same way), then the grid points nearest 45 s.

    python docs/paper_study.py out/paper_study docs/paper_study.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

FEED = "fish.drop_interval_s"
SCALE = "speed_scale"
PAPER_THROUGHPUT_S = 45.0
PAPER_SINGULATION = 0.56
SHIPPED = (2.0, 1.0)
"""(feed interval [s], speed scale) of scenarios/paper_test.toml: the design speeds, fed one fish every 2 s."""


def main(sweep_dir: str, png: str) -> None:
    s = pd.read_csv(Path(sweep_dir) / "summary.csv")
    feeds, scales = sorted(s[FEED].unique()), sorted(s[SCALE].unique())
    grid = s.set_index([SCALE, FEED])
    sing = np.array([[grid.loc[(a, f), "singulation_rate_mean"] for f in feeds] for a in scales])
    thr = np.array([[grid.loc[(a, f), "throughput_time_s_mean"] for f in feeds] for a in scales])
    fig, ax = plt.subplots(figsize=(7, 5))
    mesh = ax.pcolormesh(feeds, scales, 100 * sing, shading="nearest", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="singulation rate, mean over seeds [%]")
    ax.contour(feeds, scales, thr, levels=[PAPER_THROUGHPUT_S], colors="white", linewidths=2)
    more = ax.contour(feeds, scales, thr, levels=[20, 30, 60, 90], colors="white", linewidths=0.6, linestyles=":")
    ax.clabel(more, fmt=lambda v: f"{v:.0f} s")
    ax.contour(feeds, scales, sing, levels=[PAPER_SINGULATION], colors="orange", linewidths=1.5,
                       linestyles="--")
    shipped = ax.plot([SHIPPED[0]], [SHIPPED[1]], marker="*", color="red", markersize=14, linestyle="none")[0]
    ax.legend([plt.Line2D([], [], color="white", linewidth=2), plt.Line2D([], [], color="orange", linestyle="--"),
               shipped], [f"paper's time for throughput, {PAPER_THROUGHPUT_S:.0f} s",
                          f"paper's singulation, {100 * PAPER_SINGULATION:.0f} %", "scenarios/paper_test.toml"],
              loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize=8, facecolor="0.4",
              labelcolor="white")
    for (a, f), row in grid.iterrows():
        ax.annotate(f"{100 * row['singulation_rate_mean']:.0f}", (f, a), xytext=(0, 9), textcoords="offset points",
                    ha="center", va="center", color="w", fontsize=8)
    ax.set_xlabel("feed: interval between fish dropped [s]")
    ax.set_ylabel("belt speed scale (x the shipped profile 0.25/0.5/0.8/1.25 m/s)")
    ax.set_title(f"paper's line: singulation (paper: {100 * PAPER_SINGULATION:.0f} %) and time for throughput")
    fig.savefig(png, dpi=110, bbox_inches="tight")
    for a in scales:
        row = s[s[SCALE] == a].sort_values(FEED)
        t = row["throughput_time_s_mean"].to_numpy()
        if np.isnan(t).any():
            print(f"speed x{a:g}: a point without a mean time for throughput (all its runs failed): not interpolated")
            continue
        k = np.flatnonzero((t[:-1] <= PAPER_THROUGHPUT_S) & (t[1:] > PAPER_THROUGHPUT_S))
        if not len(k):
            print(f"speed x{a:g}: the grid does not reach {PAPER_THROUGHPUT_S:g} s")
            continue
        lo, hi = row.iloc[k[0]], row.iloc[k[0] + 1]
        w = (PAPER_THROUGHPUT_S - lo["throughput_time_s_mean"]) / (hi["throughput_time_s_mean"]
                                                                   - lo["throughput_time_s_mean"])
        at = {c: (1 - w) * lo[c] + w * hi[c] for c in (FEED, "singulation_rate_mean", "singulation_rate_ci_low",
                                                       "singulation_rate_ci_high")}
        print(f"speed x{a:g}: 45 s at one fish every {at[FEED]:.2f} s, singulation {100 * at['singulation_rate_mean']:.0f} % "
              f"[{100 * at['singulation_rate_ci_low']:.0f}, {100 * at['singulation_rate_ci_high']:.0f}]")
    near = s.assign(off=(s["throughput_time_s_mean"] - PAPER_THROUGHPUT_S).abs()).sort_values("off").head(5)
    for _, r in near.iterrows():
        print(f"feed {r[FEED]:g} s, speed x{r[SCALE]:g}: throughput {r['throughput_time_s_mean']:.1f} s "
              f"[{r['throughput_time_s_ci_low']:.1f}, {r['throughput_time_s_ci_high']:.1f}], singulation "
              f"{100 * r['singulation_rate_mean']:.0f} % [{100 * r['singulation_rate_ci_low']:.0f}, "
              f"{100 * r['singulation_rate_ci_high']:.0f}] (n = {int(r['n_ok'])})")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
