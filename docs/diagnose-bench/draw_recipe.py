"""Draw the diagnose benchmark's recipe (seeded) and write recipe.toml.

Run once per round, committed with its output; make the datasets with generate.py. Every dataset has its own
base shift (friction fish-belt / fish-fish / fish-guide x U(0.7, 1.3), drive time constant U(0.2, 0.6) s, sensor
noise) and, for an effect, its own magnitude drawn across a plausible range. The split into development and
held-out sets is drawn here too, before any diagnosis was run on them: a third held out, never tuned on.

Two rounds, each with its own random stream, so that the second cannot move the first:
- round 1 (2026-11-26, seed 20261126): 30 datasets, ten without an effect and four of each of the five
  candidate families; its entries are kept byte for byte (results measured on them stay comparable).
- round 2 (issue 41, seed 20261128): six compounds of two candidate families (the two the issue names,
  mucus+drive_droop and rigor+adhesion, and four pairs drawn from the other eight), four each of the two
  families no candidate was built for at first (guide_friction_wear, photoeye_latency) and six more without an
  effect (a no-effect dataset can now also be wrongly called "unexplained"); its own held-out third.
- round 3 (2026-11-30, seed 20261130): four more without an effect and two singles of families drawn from all seven,
  every one held out: the false alarms and the singles measured once more on data nothing was ever tuned on.
- round 4 (2026-11-30, seed 202611304): one single of each of the seven families and one more without an effect,
  every one held out, drawn with the analysis unchanged since 5f4e0c9: the held-out singles on more data.
- round 5 (2026-11-30, seed 202611305): the same design as round 4, all held out, drawn after the scan's change of
  596cf8f (touching pairs against the model, age in monotone shapes; analysis unchanged since 09605bd): that change
  was motivated by three held-out sets, so its leave-one-family-out is measured here on data nothing was tuned on.
"""
import itertools
import random
import sys
from pathlib import Path

BASE = {"mu_belt": 0.45, "mu_fish": 0.30, "mu_guide": 0.30}
COUNTS = {"none": 10, "mucus": 4, "rigor": 4, "adhesion": 4, "drive_droop": 4, "directional_friction": 4}
"""Round 1: datasets per family."""
CANDIDATE_FAMILIES = ("mucus", "rigor", "adhesion", "drive_droop", "directional_friction")
ROUND1_SEED, ROUND2_SEED = 20261126, 20261128
ROUND2_FIRST_SEED = 9000
"""Round 2's dataset seeds start above round 1's (5161-6678): no two datasets share fish, drops and ages."""
ROUND2_NAMED_COMPOUNDS = (("mucus", "drive_droop"), ("rigor", "adhesion"))
"""The compounds issue 41 reports the method failing on: always in the benchmark."""
ROUND2_COUNTS = {"compound": 6, "guide_friction_wear": 4, "photoeye_latency": 4, "none": 6}
ROUND3_SEED, ROUND3_FIRST_SEED = 20261130, 9700
ROUND4_SEED, ROUND4_FIRST_SEED = 202611304, 10400
ROUND5_SEED, ROUND5_FIRST_SEED = 202611305, 11100
"""Round 5's dataset seeds start above round 4's (10400-10778)."""
"""Round 4's dataset seeds start above round 3's (9700-10282)."""
"""Round 3's dataset seeds start above round 2's (9000-9666)."""
SINGLE_FAMILIES = (*CANDIDATE_FAMILIES, "guide_friction_wear", "photoeye_latency")
HEADER = ["# The diagnose benchmark: ten-run campaign datasets of ../shared/linesim (18 fish a run).",
          "# Drawn by draw_recipe.py (seeded); made by generate.py (commands: README.md here).",
          "# split = dev | heldout (drawn before any run). Round 1: the first 30 (2026-11-26); round 2: issue 41.", ""]


def u(rng, lo, hi, nd=3):
    return round(rng.uniform(lo, hi), nd)


def magnitude(rng, effect):
    if effect == "mucus":
        return {"mucus-mu-start": u(rng, 0.15, 0.32), "mucus-mu-end": u(rng, 0.5, 0.75), "mucus-h-start": 1.0,
                "mucus-h-end": u(rng, 24, 72, 0)}
    if effect == "rigor":
        onset = u(rng, 1, 4, 1)
        full = u(rng, 10, 20, 0)
        rs = u(rng, 30, 42, 0)
        return {"rigor-stiff-mult": u(rng, 6, 30, 1), "rigor-limit-frac": u(rng, 0.2, 0.6, 2), "rigor-onset-h": onset,
                "rigor-full-h": full, "rigor-resolve-start-h": rs, "rigor-resolve-end-h": u(rng, 60, 84, 0),
                "rigor-residual": u(rng, 0.0, 0.2, 2)}
    if effect == "adhesion":
        return {"adhesion-bond-frac": u(rng, 0.4, 1.0, 2)}
    if effect == "drive_droop":
        return {"droop-per-10kg": u(rng, 0.02, 0.08, 3)}
    if effect == "directional_friction":
        return {"mu-head": u(rng, 0.2, 0.35), "mu-tail": u(rng, 0.5, 0.7), "mu-across": u(rng, 0.38, 0.5)}
    if effect == "guide_friction_wear":  # liners x2-5 at the outfeed, the rise starting within the infeed belt
        return {"guide-wear-mult": u(rng, 2.0, 5.0, 2), "guide-wear-start-m": u(rng, 0.0, 1.5, 2)}
    if effect == "photoeye_latency":  # a slow input card or filter: 15-60 ms, with up to 20 ms jitter per edge
        return {"pe-latency-s": u(rng, 0.015, 0.06, 4), "pe-jitter-s": u(rng, 0.0, 0.02, 4)}
    if "+" in effect:  # a compound: each part's magnitude drawn as for it alone (linesim applies them all)
        return {k: v for part in effect.split("+") for k, v in magnitude(rng, part).items()}
    return {}


def base_shift(rng):
    return {"base-mu-belt": round(BASE["mu_belt"] * rng.uniform(0.7, 1.3), 3),
            "base-mu-fish": round(BASE["mu_fish"] * rng.uniform(0.7, 1.3), 3),
            "base-mu-guide": round(BASE["mu_guide"] * rng.uniform(0.7, 1.3), 3),
            "base-tau-drive": u(rng, 0.2, 0.6),
            "base-encoder-noise": u(rng, 0.002, 0.005, 4),
            "base-track-pos-noise": u(rng, 0.002, 0.005, 4),
            "base-track-yaw-noise-deg": u(rng, 1.0, 3.0, 2)}


def round1():
    """The 30 datasets of 2026-11-26, with their split: drawn exactly as they were then."""
    rng = random.Random(ROUND1_SEED)
    rows = []
    seed = 5100
    for effect, n in COUNTS.items():
        for i in range(n):
            seed += rng.randint(1, 97)
            rows.append({"name": f"{effect}_{i + 1}", "effect": effect, "seed": seed,
                         "flags": {**base_shift(rng), **magnitude(rng, effect)}})
    # the held-out third: 3 of the 10 without an effect and 7 of the 20 with one, at least one each
    held = set(rng.sample([r["name"] for r in rows if r["effect"] == "none"], 3))
    for effect in COUNTS:
        if effect != "none":
            held.add(rng.choice([r["name"] for r in rows if r["effect"] == effect]))
    rest = [r["name"] for r in rows if r["effect"] != "none" and r["name"] not in held]
    held.update(rng.sample(rest, 2))
    return [r | {"split": "heldout" if r["name"] in held else "dev"} for r in rows]


def round2():
    """Issue 41's 20 datasets, with their own held-out third (7 of 20: two without an effect, two compounds, one of
    each new family and one more drawn from the rest), drawn here before any of them was made or diagnosed."""
    rng = random.Random(ROUND2_SEED)
    pairs = [p for p in itertools.combinations(CANDIDATE_FAMILIES, 2)
             if p not in ROUND2_NAMED_COMPOUNDS and p[::-1] not in ROUND2_NAMED_COMPOUNDS]
    compounds = list(ROUND2_NAMED_COMPOUNDS) + rng.sample(pairs, ROUND2_COUNTS["compound"] - len(ROUND2_NAMED_COMPOUNDS))
    effects = (["+".join(p) for p in compounds] + ["guide_friction_wear"] * ROUND2_COUNTS["guide_friction_wear"]
               + ["photoeye_latency"] * ROUND2_COUNTS["photoeye_latency"] + ["none"] * ROUND2_COUNTS["none"])
    rows, seed, count = [], ROUND2_FIRST_SEED, dict(COUNTS)  # numbered on from round 1: none_11, ...
    for effect in effects:
        seed += rng.randint(1, 97)
        count[effect] = count.get(effect, 0) + 1
        name = f"{effect}_{count[effect]}" if "+" not in effect else effect
        rows.append({"name": name, "effect": effect, "seed": seed, "flags": {**base_shift(rng), **magnitude(rng, effect)}})
    kind = {r["name"]: ("compound" if "+" in r["effect"] else r["effect"]) for r in rows}
    held = set(rng.sample([n for n in kind if kind[n] == "none"], 2))
    held.update(rng.sample([n for n in kind if kind[n] == "compound"], 2))
    for family in ("guide_friction_wear", "photoeye_latency"):
        held.add(rng.choice([n for n in kind if kind[n] == family]))
    held.add(rng.choice([n for n in kind if kind[n] != "none" and n not in held]))
    return [r | {"split": "heldout" if r["name"] in held else "dev"} for r in rows]


def round3(before: list[dict]):
    """2026-11-30: four without an effect and two singles of two families drawn from all seven; all held out, drawn
    before any was made. Numbered on from the rounds ``before`` (none_17, ...)."""
    rng = random.Random(ROUND3_SEED)
    return _held_out(rng, ["none"] * 4 + rng.sample(SINGLE_FAMILIES, 2), before, ROUND3_FIRST_SEED)


def round4(before: list[dict]):
    """2026-11-30: one single of each of the seven families and one without an effect, in a drawn order; all held out,
    drawn before any was made. Numbered on from the rounds ``before``."""
    rng = random.Random(ROUND4_SEED)
    return _held_out(rng, rng.sample([*SINGLE_FAMILIES, "none"], len(SINGLE_FAMILIES) + 1), before, ROUND4_FIRST_SEED)


def round5(before: list[dict]):
    """2026-11-30, evening: as round 4 (one single of each family, one without an effect), its own stream; all held
    out, drawn before any was made. Numbered on from the rounds ``before``."""
    rng = random.Random(ROUND5_SEED)
    return _held_out(rng, rng.sample([*SINGLE_FAMILIES, "none"], len(SINGLE_FAMILIES) + 1), before, ROUND5_FIRST_SEED)


def _held_out(rng, effects: list[str], before: list[dict], first_seed: int) -> list[dict]:
    """A held-out round's rows for ``effects`` in order: seeds on from ``first_seed``, each its own base shift and
    magnitude, named on from the rounds ``before`` (none_17, ...)."""
    count = {}
    for r in before:
        count[r["effect"]] = count.get(r["effect"], 0) + 1
    rows, seed = [], first_seed
    for effect in effects:
        seed += rng.randint(1, 97)
        count[effect] = count.get(effect, 0) + 1
        rows.append({"name": f"{effect}_{count[effect]}", "effect": effect, "seed": seed, "split": "heldout",
                     "flags": {**base_shift(rng), **magnitude(rng, effect)}})
    return rows


def entry(r):
    return ["[[dataset]]", f'name = "{r["name"]}"', f'effect = "{r["effect"]}"', f'seed = {r["seed"]}',
            f'split = "{r["split"]}"',
            "flags = { " + ", ".join(f'"{k}" = {v}' for k, v in r["flags"].items()) + " }", ""]


def recipe_text():
    earlier = round1() + round2()
    earlier += round3(earlier)
    earlier += round4(earlier)
    return "\n".join(HEADER + [line for r in earlier + round5(earlier) for line in entry(r)])


def main(out: Path):
    out.write_text(recipe_text())


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("recipe.toml"))
