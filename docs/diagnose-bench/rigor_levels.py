"""Rigor's level responses at many stiffness values, and the rigor fit with subsets of them (docs/diagnosis.md,
"Rigor: where our fish's response bends").  Not part of the product: a measurement beside the benchmark.

    python docs/diagnose-bench/rigor_levels.py DATASET [DATASET ...] --cache DIR

Each dataset is calibrated as ``diagnose`` calibrates it, with joint stiffening simulated at k = 1, 2.5, 5, 10, 20
and 40 (the responses are kept in DIR, so a second call only scores).  Printed per dataset: each fit run's own best
stiffness beside the truth's (when a NAME.truth.json lies beside the dataset), how far the rows still are from their
value at the largest k, and the rigor fit's held-out gain and strength with each set of values.
"""

from __future__ import annotations

import argparse
import json
import pickle
from dataclasses import replace
from pathlib import Path

import numpy as np

from plant.contract.measured import read_dataset

from fishfmu.analysis import levels as L
from fishfmu.analysis.calibrate import calibrate_with_pool
from fishfmu.analysis.resim import measured_data_plant, pool_for

DENSE = replace(L.RIGOR, grid=(1.0, 2.5, 5.0, 10.0, 20.0, 40.0))
SUBSETS = {"k = 5, 20": (0.0, 5.0, 20.0), "k = 1, 2.5, 20": (0.0, 1.0, 2.5, 20.0), "all": None}


def truth_k(m: dict, h: float) -> float:
    """The independent simulator's extra stiffness at h hours (its truth.json: smoothstep onset, plateau, resolve)."""
    def step(x: float) -> float:
        x = min(max(x, 0.0), 1.0)
        return 3 * x * x - 2 * x ** 3
    if h < m["rigor_onset_h"]:
        r = 0.0
    elif h < m["rigor_full_h"]:
        r = step((h - m["rigor_onset_h"]) / (m["rigor_full_h"] - m["rigor_onset_h"]))
    elif h < m["rigor_resolve_start_h"]:
        r = 1.0
    else:
        r = 1 - (1 - m["rigor_residual"]) * step((h - m["rigor_resolve_start_h"])
                                                 / (m["rigor_resolve_end_h"] - m["rigor_resolve_start_h"]))
    return (m["rigor_stiff_mult"] - 1) * r


def only_values(resp: L.Responses, keep: tuple[float, ...] | None) -> L.Responses:
    if keep is None:
        return resp
    v = resp.values["rigor"]
    idx = [i for i, x in enumerate(v) if x in keep]
    return replace(resp, values={**resp.values, "rigor": v[idx]}, delta={**resp.delta, "rigor": resp.delta["rigor"][:, idx]})


def responses_of(path: Path, cache: Path) -> L.Responses:
    out = cache / f"responses_{path.name}.pkl"
    if not out.exists():
        with pool_for(2) as pool:
            cal = calibrate_with_pool(read_dataset(path), measured_data_plant(), pool, 0, print,
                                      levels=(L.FRICTION, DENSE))
        out.write_bytes(pickle.dumps(cal.responses))
    return pickle.loads(out.read_bytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--cache", type=Path, required=True)
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    for path in a.datasets:
        on = responses_of(path, a.cache).only(L.MODELS["rigor_mortis"].kinds)
        label = path.with_name(path.name + ".truth.json")
        m = json.loads(label.read_text())["magnitude"] if label.exists() else {}
        own = L.run_levels(on)
        if "rigor_stiff_mult" in m:
            own["truth_k"] = [truth_k(m, h) for h in own["hours_post_mortem"]]
        print(f"== {path.name}\n{own.to_string(index=False)}")
        d, w = on.delta["rigor"], on.row_weight
        dist = np.sqrt([np.sum(w * (d[:, j] - d[:, -1]) ** 2) for j in range(d.shape[1])])
        print("rows' distance from their value at the largest k, over that at k = 0:",
              dict(zip(on.values["rigor"].tolist(), np.round(dist / dist[0], 2).tolist())))
        for name, keep in SUBSETS.items():
            r = only_values(on, keep)
            rng = np.random.default_rng(0)
            ref, fit = L.fit_model(L.MODELS["constant"], r, rng), L.fit_model(L.MODELS["rigor_mortis"], r, rng)
            gain, ci = L.gain_over(ref, fit, rng)
            k0, k = fit.values["joint_stiffening"], fit.values["stiffness_gain"]
            print(f"{name}: gain {gain:.1%} [{ci[0]:.1%}, {ci[1]:.1%}], x{(1 + k0 + k) / (1 + k0):.3g} at the peak, "
                  f"{fit.values}")


if __name__ == "__main__":
    main()
