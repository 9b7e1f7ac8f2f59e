"""Draw the diagnose benchmark's recipe once (seeded) and write recipe.toml.

Run once, committed with its output; regenerate the datasets with generate.py. Every dataset has
its own base shift (friction fish-belt / fish-fish / fish-guide x U(0.7, 1.3), drive time
constant U(0.2, 0.6) s, sensor noise) and, for an effect, its own magnitude drawn across a
plausible range. The split into development and held-out sets is drawn here too, before any
diagnosis was run on them: a third held out, never tuned on.
"""
import random
import sys
from pathlib import Path

RNG = random.Random(20261126)
BASE = {"mu_belt": 0.45, "mu_fish": 0.30, "mu_guide": 0.30}
COUNTS = {"none": 10, "mucus": 4, "rigor": 4, "adhesion": 4, "drive_droop": 4, "directional_friction": 4}


def u(lo, hi, nd=3):
    return round(RNG.uniform(lo, hi), nd)


def magnitude(effect):
    if effect == "mucus":
        return {"mucus-mu-start": u(0.15, 0.32), "mucus-mu-end": u(0.5, 0.75), "mucus-h-start": 1.0,
                "mucus-h-end": u(24, 72, 0)}
    if effect == "rigor":
        onset = u(1, 4, 1)
        full = u(10, 20, 0)
        rs = u(30, 42, 0)
        return {"rigor-stiff-mult": u(6, 30, 1), "rigor-limit-frac": u(0.2, 0.6, 2), "rigor-onset-h": onset,
                "rigor-full-h": full, "rigor-resolve-start-h": rs, "rigor-resolve-end-h": u(60, 84, 0),
                "rigor-residual": u(0.0, 0.2, 2)}
    if effect == "adhesion":
        return {"adhesion-bond-frac": u(0.4, 1.0, 2)}
    if effect == "drive_droop":
        return {"droop-per-10kg": u(0.02, 0.08, 3)}
    if effect == "directional_friction":
        return {"mu-head": u(0.2, 0.35), "mu-tail": u(0.5, 0.7), "mu-across": u(0.38, 0.5)}
    return {}


def base_shift():
    return {"base-mu-belt": round(BASE["mu_belt"] * RNG.uniform(0.7, 1.3), 3),
            "base-mu-fish": round(BASE["mu_fish"] * RNG.uniform(0.7, 1.3), 3),
            "base-mu-guide": round(BASE["mu_guide"] * RNG.uniform(0.7, 1.3), 3),
            "base-tau-drive": u(0.2, 0.6),
            "base-encoder-noise": u(0.002, 0.005, 4),
            "base-track-pos-noise": u(0.002, 0.005, 4),
            "base-track-yaw-noise-deg": u(1.0, 3.0, 2)}


def main(out: Path):
    rows = []
    seed = 5100
    for effect, n in COUNTS.items():
        for i in range(n):
            seed += RNG.randint(1, 97)
            rows.append({"name": f"{effect}_{i + 1}", "effect": effect, "seed": seed,
                         "flags": {**base_shift(), **magnitude(effect)}})
    # the held-out third: 3 of the 10 without an effect and 7 of the 20 with one, at least one each
    held = set(RNG.sample([r["name"] for r in rows if r["effect"] == "none"], 3))
    for effect in COUNTS:
        if effect != "none":
            held.add(RNG.choice([r["name"] for r in rows if r["effect"] == effect]))
    rest = [r["name"] for r in rows if r["effect"] != "none" and r["name"] not in held]
    held.update(RNG.sample(rest, 2))
    lines = ["# The diagnose benchmark: 30 ten-run campaign datasets of ../shared/linesim (18 fish a run).",
             "# Drawn by draw_recipe.py (seeded); made by generate.py. split = dev | heldout (drawn before any run).", ""]
    for r in rows:
        lines += ["[[dataset]]", f'name = "{r["name"]}"', f'effect = "{r["effect"]}"', f'seed = {r["seed"]}',
                  f'split = "{"heldout" if r["name"] in held else "dev"}"',
                  "flags = { " + ", ".join(f'"{k}" = {v}' for k, v in r["flags"].items()) + " }", ""]
    out.write_text("\n".join(lines))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("recipe.toml"))
