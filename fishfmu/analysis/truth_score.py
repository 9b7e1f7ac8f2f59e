"""A diagnosis scored against a labelled dataset's truth (``NAME.truth.json`` beside it, e.g. from the independent
simulator ``../shared/linesim``): what ``fishfmu bench diagnose --labelled`` counts (issue 41's benchmark).

Pure functions over the two documents as dicts: the generator's ``truth.json`` (``effect``, ``"a+b"`` for a
compound, and from newer generators ``effects``, a list) and ``diagnosis.json`` (``cause``, and since issue 41
``causes``, ``answer`` -- ``named``, ``fits`` or ``unexplained`` -- and ``unexplained``, findings each with a
``location`` {``kind``, ``id``} and a ``covariate``). A document from before issue 41 (``cause`` alone) is read as
naming that cause or answering "fits".

Each dataset is one of:
- ``none``: no effect; right when the answer is "fits", a false alarm when it names a cause or calls an
  unexplained discrepancy;
- ``single``: one family whose candidate the run could name; right (that candidate alone named), wrong (any
  other named) or none (nothing named);
- ``compound``: several families; all of their candidates named, and "at least one right and none wrong";
- ``open``: one family without a candidate the run could name (none built for it, or switched off with
  ``--without``): the answer must be "unexplained" with a finding located where the family acts
  (:data:`FAMILIES`), and naming any cause is wrong. The leave-one-family-out measure scores a single's re-run
  with its candidate switched off this way.
Nothing here is used by ``diagnose`` itself.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from statistics import median
from typing import Any


@dataclass(frozen=True)
class Family:
    """An effect family of the generator: the candidate that names it, and where its discrepancy shows."""
    candidate: str | None
    """The candidate of :data:`fishfmu.analysis.candidates.CANDIDATES` that names it (None: no candidate)."""
    kinds: frozenset[str]
    """Location kinds of ``diagnosis.json``'s unexplained findings where it acts (the contract's: drop, transfer,
    belt, photoeye, drive, guide, pairs); a finding at one of these is "located right"."""
    covariates: frozenset[str]
    """Covariates it follows (columns of :mod:`fishfmu.analysis.observations`' tables): reported, not required."""
    why: str


FAMILIES: dict[str, Family] = {
    "mucus": Family(
        "mucus_friction", frozenset({"drop", "transfer"}), frozenset({"hours_post_mortem", "hours_monotone"}),
        "fish-belt friction changes with age; friction shows only where a fish slips against a belt, i.e. where it "
        "is taken up to the belt's speed: landing on the infeed and the transfers (riding along, nothing slips)"),
    "rigor": Family(
        "rigor_mortis", frozenset({"photoeye"}), frozenset({"hours_post_mortem", "hours_monotone"}),
        "joints stiffen and their range shrinks with age; a stiff fish bridges the belts' steps and ends instead of "
        "draping over them, which the photo-eyes (15 mm above each belt near its end) see as a changed blocked share "
        "of a passage; the fish's slip hardly changes"),
    "directional_friction": Family(
        "directional_friction", frozenset({"drop", "transfer"}), frozenset({"heading"}),
        "friction depends on the direction of slip (head or tail first); as with mucus it shows only where the fish "
        "slips against a belt (the drop, the transfers), and follows the fish's heading there"),
    "drive_droop": Family(
        "drive_droop", frozenset({"drive"}), frozenset({"load_kg", "load_force_n"}),
        "the belt's own speed sags under the mass it carries: the drive's speed against its setpoint (belts.csv), "
        "following the load on the belt"),
    "adhesion": Family(
        "adhesion", frozenset({"pairs", "transfer"}), frozenset({"touching"}),
        "touching fish stick together: a touching pair does not part as the next belt takes the leader up faster, "
        "which shows in the pairs' separation at a transfer, following whether they touch"),
    "photoeye_latency": Family(
        "photoeye_latency", frozenset({"photoeye"}), frozenset({"belt_speed_mps"}),
        "a sensor effect, no physics: every photo-eye edge is reported late; against the tracks' crossing times "
        "the edges lag at the eyes alone, a position error that grows with the belt's speed under the eye"),
    "guide_friction_wear": Family(
        "guide_wear", frozenset({"guide", "belt"}), frozenset({"x_m", "touching"}),
        "fish-guide friction rises along the line; only fish touching a guide feel it, as slip while riding a belt "
        "(a fish held back against the belt), growing toward the outfeed (x) and with contact"),
}
"""The generator's families (``truth.json``'s effect names). A family not listed (a hidden exam's) has no candidate
and no location that counts as right: only "no wrong cause" can be scored for it."""

SINGLE_OUTCOMES = ("right", "wrong", "none")
OPEN_OUTCOMES = ("located", "elsewhere", "fits", "wrong")
"""An open-set run: unexplained and located where the family acts; unexplained elsewhere; nothing found; a cause
named that the data does not hold."""


def family(name: str) -> Family:
    return FAMILIES.get(name, Family(None, frozenset(), frozenset(), "not known to the benchmark"))


def truth_families(truth: dict) -> tuple[str, ...]:
    """The truth's effect families (empty: no effect)."""
    effects = truth.get("effects") or str(truth.get("effect", "none")).split("+")
    return tuple(e for e in effects if e and e != "none")


def named_causes(diagnosis: dict) -> tuple[str, ...]:
    """The causes a diagnosis named (``causes``; before issue 41 the one ``cause``)."""
    causes = diagnosis.get("causes")
    if causes is None:
        causes = str(diagnosis.get("cause", "none")).split("+")
    return tuple(c for c in causes if c and c != "none")


def answer_of(diagnosis: dict) -> str:
    """``named``, ``fits`` or ``unexplained`` (a document from before issue 41: ``named`` or ``fits``)."""
    if diagnosis.get("answer"):
        return str(diagnosis["answer"])
    if named_causes(diagnosis):
        return "named"
    return "unexplained" if diagnosis.get("unexplained") else "fits"


def nameable(families: tuple[str, ...], available: frozenset[str]) -> frozenset[str]:
    """The candidates among ``available`` (registered and not left out) that name one of ``families``."""
    return frozenset(c for c in (family(f).candidate for f in families) if c is not None and c in available)


def kind_of(families: tuple[str, ...], available: frozenset[str]) -> str:
    if not families:
        return "none"
    if len(families) > 1:
        return "compound"
    return "single" if nameable(families, available) else "open"


def single_outcome(families: tuple[str, ...], diagnosis: dict, available: frozenset[str]) -> str:
    """right (its candidate alone named), wrong (any other named, alone or beside it) or none."""
    got = frozenset(named_causes(diagnosis))
    if not got:
        return "none"
    return "right" if got == nameable(families, available) else "wrong"


def compound_outcome(families: tuple[str, ...], diagnosis: dict, available: frozenset[str]) -> dict[str, Any]:
    """``all_named``: every part's candidate named (others may be named too: counted as wrong);
    ``one_right_none_wrong``: at least one part's candidate named and nothing else."""
    got, want = frozenset(named_causes(diagnosis)), nameable(families, available)
    return {"all_named": bool(want) and want <= got, "one_right_none_wrong": bool(got & want) and got <= want,
            "right": sorted(got & want), "wrong": sorted(got - want)}


def open_outcome(families: tuple[str, ...], diagnosis: dict, available: frozenset[str]) -> dict[str, Any]:
    """A run in which some of the truth's families had no candidate to name them (``available``: what it could
    name): every named cause must be one of the others' candidates, and a finding must be located where one of the
    unnameable families acts. Outcome: located, elsewhere, fits (no finding) or wrong (a cause the data does not
    hold)."""
    still = nameable(families, available)
    unnamed = [f for f in families if family(f).candidate not in still]
    kinds = frozenset().union(*(family(f).kinds for f in unnamed))
    covariates = frozenset().union(*(family(f).covariates for f in unnamed))
    findings = diagnosis.get("unexplained") or []
    at = [x for x in findings if (x.get("location") or {}).get("kind") in kinds]
    wrong = sorted(frozenset(named_causes(diagnosis)) - still)
    if wrong:
        outcome = "wrong"
    elif not findings:
        outcome = "fits"
    else:
        outcome = "located" if at else "elsewhere"
    return {"outcome": outcome, "answer": answer_of(diagnosis), "wrong": wrong, "unnamed": unnamed,
            # a finding names its covariate for the reader ("covariate") and by its column ("covariate_key")
            "following": any(x.get("covariate_key", x.get("covariate")) in covariates for x in at),
            "where": sorted({f"{(x.get('location') or {}).get('kind')}:{(x.get('location') or {}).get('id')}"
                             for x in findings})}


def score(truth: dict, diagnosis: dict, available: frozenset[str], open_run: dict | None = None) -> dict[str, Any]:
    """One dataset's scores. ``available``: the candidates the main run could name; ``open_run``: its re-run with
    the family's candidates switched off ({``left_out``: [...], ``diagnosis``: {...}}), scored as an open run."""
    families = truth_families(truth)
    kind = kind_of(families, available)
    got = named_causes(diagnosis)
    out: dict[str, Any] = {"kind": kind, "families": list(families), "expected": sorted(nameable(families, available)),
                           "named": list(got), "answer": answer_of(diagnosis),
                           "label": "+".join(got) if got else answer_of(diagnosis)}
    if kind == "single":
        out["single"] = single_outcome(families, diagnosis, available)
    elif kind == "compound":
        out["compound"] = compound_outcome(families, diagnosis, available)
    elif kind == "open":  # no candidate for it at all: the main run is its open-set run
        out["open_set"] = open_outcome(families, diagnosis, available) | {"left_out": [], "source": "no candidate"}
    if open_run is not None:
        left = frozenset(open_run["left_out"])
        out["open_set"] = (open_outcome(families, open_run["diagnosis"], available - left)
                           | {"left_out": sorted(left), "source": "--without"})
    return out


def _rate(k: int, n: int) -> float | None:
    return k / n if n else None


def _times(values: list[float]) -> dict[str, float] | None:
    v = [x for x in values if x is not None]
    return {"mean": sum(v) / len(v), "median": float(median(v)), "max": max(v), "n": len(v)} if v else None


def summarise(rows: list[dict]) -> dict[str, Any]:
    """The benchmark's tables over scored rows (each {``score``: :func:`score`'s, ``wall_s``, ``open_wall_s``}):
    singles' confusion (truth's candidate -> what was named, or the answer) and outcomes; no-effect datasets'
    answers and false alarms; compounds' two measures; the open set's outcomes (overall and per family); the
    time of a diagnosis (main runs; open-set re-runs apart)."""
    singles = [r["score"] for r in rows if r["score"]["kind"] == "single"]
    nones = [r["score"] for r in rows if r["score"]["kind"] == "none"]
    compounds = [r["score"] for r in rows if r["score"]["kind"] == "compound"]
    opens = [r["score"] for r in rows if "open_set" in r["score"]]
    confusion: dict[str, Counter] = {}
    for s in singles:
        confusion.setdefault(s["expected"][0], Counter())[s["label"]] += 1
    single_counts = Counter(s["single"] for s in singles)
    none_counts = Counter(s["answer"] for s in nones)
    open_counts = Counter(s["open_set"]["outcome"] for s in opens)
    by_family: dict[str, Counter] = {}
    for s in opens:
        by_family.setdefault("+".join(s["families"]), Counter())[s["open_set"]["outcome"]] += 1
    alarms = len(nones) - none_counts["fits"]
    both = sum(c["compound"]["all_named"] for c in compounds)
    safe = sum(c["compound"]["one_right_none_wrong"] for c in compounds)
    return {
        "datasets": len(rows),
        "singles": {"n": len(singles), **{k: single_counts[k] for k in SINGLE_OUTCOMES},
                    "right_rate": _rate(single_counts["right"], len(singles)),
                    "confusion": {t: dict(c) for t, c in sorted(confusion.items())}},
        "no_effect": {"n": len(nones), "fits": none_counts["fits"], "named": none_counts["named"],
                      "unexplained": none_counts["unexplained"], "false_alarms": alarms,
                      "false_alarm_rate": _rate(alarms, len(nones))},
        "compounds": {"n": len(compounds), "all_named": both, "all_named_rate": _rate(both, len(compounds)),
                      "one_right_none_wrong": safe, "one_right_none_wrong_rate": _rate(safe, len(compounds))},
        "open_set": {"n": len(opens), **{k: open_counts[k] for k in OPEN_OUTCOMES},
                     "following": sum(s["open_set"]["outcome"] == "located" and s["open_set"]["following"]
                                      for s in opens),
                     "located_rate": _rate(open_counts["located"], len(opens)),
                     "wrong_rate": _rate(open_counts["wrong"], len(opens)),
                     "by_family": {f: dict(c) for f, c in sorted(by_family.items())}},
        "wall_s": _times([r.get("wall_s") for r in rows]),
        "open_wall_s": _times([r.get("open_wall_s") for r in rows]),
    }


def summarise_by_split(rows: list[dict]) -> dict[str, Any]:
    """:func:`summarise` over every row, and per split (each row's ``split``: dev, heldout; ``unlisted`` when the
    recipe has no such dataset)."""
    splits = sorted({r.get("split", "unlisted") for r in rows})
    return {"all": summarise(rows), "splits": {s: summarise([r for r in rows if r.get("split", "unlisted") == s])
                                               for s in splits}}


def is_right(scored: dict) -> bool:
    """The main run's answer is the truth: no effect and "fits"; a single's candidate alone; every part of a
    compound and nothing else; for a family without a candidate, unexplained and located where it acts."""
    kind = scored["kind"]
    if kind == "none":
        return scored["answer"] == "fits"
    if kind == "single":
        return scored["single"] == "right"
    if kind == "compound":
        return scored["compound"]["all_named"] and not scored["compound"]["wrong"]
    return scored["open_set"]["outcome"] == "located"
