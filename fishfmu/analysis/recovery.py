"""Parameter recovery on labelled data: a labelled dataset's truth (``NAME.truth.json`` beside it, e.g. from the
independent simulator of ``fishfmu bench diagnose --labelled``) in the candidate's own terms
(:attr:`fishfmu.analysis.candidate.Candidate.terms`), and the fitted strength against it.

The truth's parameters are the generator's, read from its label as a user would read a lab's report of the line;
its laws are the ones its ``truth.json`` describes.  Nothing here is used by ``diagnose`` itself.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from plant.contract.measured import Dataset

from fishfmu.analysis.candidates import CANDIDATES

G_MPS2 = 9.81
RECOVERED_WITHIN = 1.5
"""A fitted strength counts as recovered when it is within this factor of the truth (issue 40's target)."""


def truth_terms(effect: str, magnitude: dict[str, float], dataset: Dataset) -> dict[str, float]:
    """The generator's truth (``NAME.truth.json``'s ``magnitude``, the independent simulator's parameters) in the
    candidate's own terms (:attr:`fishfmu.analysis.candidate.Candidate.terms`); empty for an effect without them."""
    m = magnitude
    if effect == "mucus_friction":  # log-time drying between two ages (the simulator's law, its truth.json says)
        def mu(h: float) -> float:
            x = np.clip(np.log(h / m["mucus_h_start"]) / np.log(m["mucus_h_end"] / m["mucus_h_start"]), 0.0, 1.0)
            return m["mucus_mu_start"] + (m["mucus_mu_end"] - m["mucus_mu_start"]) * float(x)
        return {"friction_1h": mu(1.0), "friction_48h": mu(48.0), "rise_1h_to_48h": mu(48.0) / mu(1.0)}
    if effect == "rigor_mortis":  # full rigor from rigor_full_h until rigor_resolve_start_h
        return {"stiffness_factor_at_peak": m["rigor_stiff_mult"],
                "peak_h": 0.5 * (m["rigor_full_h"] + m["rigor_resolve_start_h"])}
    if effect == "drive_droop":
        return {"speed_lost_per_10kg": m["droop_per_10kg"]}
    if effect == "directional_friction" and "mu_head" in m:
        return {"head_tail_friction_ratio": m["mu_head"] / m["mu_tail"]}
    if effect == "adhesion" and m.get("adhesion_bond_frac", 0.0) > 0.0:
        # a bond pulls two body segments together with bond_frac x a segment's weight: a fifth of a median fish
        weight = float(np.median(pd.concat([r.fish["weight_kg"] for r in dataset.runs])))
        return {"bond_force_n": m["adhesion_bond_frac"] * G_MPS2 * weight / 5.0}
    if effect == "photoeye_latency" and "pe_latency_s" in m:
        # each edge late by the latency and a jitter uniform up to pe_jitter_s (its truth.json says): half of it on
        # average
        return {"latency_s": m["pe_latency_s"] + 0.5 * m.get("pe_jitter_s", 0.0)}
    return {}


def recovery(effect: str, fitted: dict[str, float], truth: dict[str, float]) -> dict[str, Any]:
    """The candidate's primary term fitted against the truth: their ratio and whether it is within
    :data:`RECOVERED_WITHIN`."""
    cand = CANDIDATES.get(effect)
    key = cand.primary if cand is not None else ""
    if not key or key not in fitted or key not in truth or not truth[key]:
        return {}
    ratio = fitted[key] / truth[key]
    return {"term": key, "fitted": fitted[key], "truth": truth[key], "ratio": ratio,
            "within": bool(1.0 / RECOVERED_WITHIN <= ratio <= RECOVERED_WITHIN)}
