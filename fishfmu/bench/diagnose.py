"""Benchmark of ``diagnose`` on hidden effects: how often it names the right cause, over many seeds.

    fishfmu bench diagnose --seeds 5 --json bench-results/diagnose_bench.json
    fishfmu bench diagnose --labelled BENCH --recipe docs/diagnose-bench/recipe.toml [--open-set] --json out.json

With ``--labelled DIR``: every dataset folder in DIR that has a ``NAME.truth.json`` beside it (labelled data,
e.g. from an independent simulator) is diagnosed as a user would (calibrating first) and scored against its
truth (:mod:`fishfmu.analysis.truth_score`: singles right / wrong / none, no-effect datasets' false alarms,
compounds' two measures, families without a candidate); with ``--open-set``, each single-effect dataset is
diagnosed once more with its family's candidate switched off (``diagnose(..., without=...)``): the
leave-one-family-out measure of issue 41, which must answer "unexplained" where the family acts. The time of
each diagnosis is recorded (issue 41's target: 5 minutes per ten-run dataset). docs/diagnose-bench/README.md
has the recipe and the commands.

Each effect (and none) is simulated on the small line and run design of ``fishfmu.analysis.synthetic`` (that of tests/test_diagnose.py) with
a different seed per repetition (different fish, drops, noise), diagnosed without being told, and
the named cause recorded; the result is a confusion table and the accuracy per effect.
"""

from __future__ import annotations

import inspect
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from plant.contract.measured import read_dataset
from plant.errors import InputError
from plant.validation import read_toml

from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.analysis.diagnose import diagnose
from fishfmu.analysis.diagnose_report import diagnosis_document
from fishfmu.analysis.recovery import RECOVERED_WITHIN, recovery, truth_terms
from fishfmu.analysis.truth_score import FAMILIES, is_right, kind_of, nameable, score, summarise_by_split, truth_families
from fishfmu.analysis.synthetic import (EFFECTS, SMALL_KPI, SMALL_LINE, SMALL_RUNS, SMALL_SPEEDS, make_dataset,
                                        synthetic_base)


def run_bench(seeds: list[int], effects: tuple[str, ...] = EFFECTS, strength: float = 1.0, workers: int = 2,
              on_row: Callable[[dict], None] | None = None) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        for effect in effects:
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                base = synthetic_base()
                path = make_dataset(Path(tmp) / "data", effect, SMALL_LINE, SMALL_KPI, SMALL_RUNS, SMALL_SPEEDS,
                                    seed=seed, strength=strength, base=base)
                d = diagnose(read_dataset(path), base, workers=workers, seed=seed, calibrate=False)  # base: known
                rows.append({"effect": effect, "seed": seed, "cause": d.cause, "correct": d.cause == effect,
                             "heldout_gain": d.fit.heldout_gain if d.fit else 0.0, "wall_s": time.perf_counter() - t0})
                if on_row is not None:
                    on_row(rows[-1])
    return pd.DataFrame(rows)


def bench(seeds: int = 5, first_seed: int = 100, strength: float = 1.0, workers: int = 2,
          on_row: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """The confusion table and accuracy per effect over ``seeds`` seeds from ``first_seed``."""
    table = run_bench(list(range(first_seed, first_seed + seeds)), strength=strength, workers=workers, on_row=on_row)
    confusion = pd.crosstab(table["effect"], table["cause"])
    accuracy = table.groupby("effect")["correct"].mean()
    return {"runs": table.to_dict(orient="records"), "accuracy": accuracy.to_dict(),
            "overall": float(table["correct"].mean()), "confusion": confusion.to_dict(), "strength": strength}


TRUTH_NAMES = {"none": "none", **{name: f.candidate for name, f in FAMILIES.items() if f.candidate}}
"""A label's effect (``NAME.truth.json``) as the candidate that names it
(:data:`~fishfmu.analysis.truth_score.FAMILIES`)."""
KEPT = ("cause", "causes", "answer", "left_out", "unexplained", "decision", "undecided")
"""What a row keeps of each diagnosis.json (what the scores are computed from; the rest is in the tests)."""
TARGET_S = 300.0
"""Issue 41: at most 5 minutes per ten-run dataset on the 2-core machine."""


def read_splits(recipe: Path | None) -> dict[str, str]:
    """Dataset name -> its split (``dev``, ``heldout``) from a benchmark recipe (``docs/diagnose-bench/recipe.toml``)."""
    if recipe is None:
        return {}
    doc = read_toml(recipe)
    return {str(d["name"]): str(d.get("split", "dev")) for d in doc.get("dataset", [])}


def open_set_supported() -> bool:
    """Whether this ``diagnose`` can switch candidates off (``without=``, issue 41): the open-set runs need it."""
    return "without" in inspect.signature(diagnose).parameters


def _diagnosis(dataset, workers: int, without: tuple[str, ...] = ()) -> tuple[Any, dict, float]:
    """``diagnose`` as a user runs it (calibrating first), its diagnosis.json as a dict, and its wall time [s]."""
    t0 = time.perf_counter()
    d = diagnose(dataset, workers=workers, without=without) if without else diagnose(dataset, workers=workers)
    doc = diagnosis_document(d)
    return d, {k: doc[k] for k in KEPT if k in doc}, time.perf_counter() - t0


def _tests(d) -> dict:
    return {t.candidate: {"p": t.p_value, "gain": t.heldout_gain, "ci95": list(t.heldout_gain_ci95), "effect": t.effect}
            for t in d.judgement.tests}


def labelled_row(data: Path, truth: dict, split: str, workers: int, open_set: bool,
                 available: frozenset[str]) -> dict[str, Any]:
    """One labelled dataset diagnosed (and with ``open_set``, re-diagnosed with its family's candidate switched off
    when it has one), scored against its truth (:func:`fishfmu.analysis.truth_score.score`)."""
    families = truth_families(truth)
    effect = "+".join(TRUTH_NAMES.get(f, f) for f in families) or "none"
    t0 = time.perf_counter()
    dataset = read_dataset(data)
    read_s = time.perf_counter() - t0
    d, doc, wall_s = _diagnosis(dataset, workers)
    row: dict[str, Any] = {"dataset": data.name, "split": split, "effect": effect, "families": list(families),
                           "truth": {k: truth[k] for k in ("effect", "effects", "magnitude") if k in truth},
                           "cause": d.cause, "diagnosis": doc, "tests": _tests(d),
                           "fit": ({"gain": d.fit.heldout_gain, "ci95": list(d.fit.heldout_gain_ci95),
                                    "values": d.fit.values} if d.fit else None),
                           "extension": d.extension, "terms": d.terms,
                           "calibration": d.calibration.changed(d.calibration.base) if d.calibration else {},
                           "wall_s": read_s + wall_s, "runs_in_dataset": len(dataset.runs)}
    if kind_of(families, available) == "single":
        truth_in_terms = truth_terms(effect, truth.get("magnitude", {}), dataset)
        row |= {"truth_terms": truth_in_terms,
                "recovery": recovery(effect, d.terms, truth_in_terms) if d.cause == effect else {}}
        left_out = tuple(sorted(nameable(families, available)))
        if open_set:
            _, open_doc, row["open_wall_s"] = _diagnosis(dataset, workers, without=left_out)
            row["open_set_run"] = {"left_out": list(left_out), "diagnosis": open_doc}
    row["score"] = score(truth, doc, available, row.get("open_set_run"))
    row["correct"] = is_right(row["score"])
    return row


def bench_labelled(folder: Path, workers: int = 2, on_row: Callable[[dict], None] | None = None,
                   splits: dict[str, str] | None = None, only: str | None = None,
                   on_done: Callable[[dict], None] | None = None, open_set: bool = False) -> dict[str, Any]:
    """Diagnose every labelled dataset in ``folder`` as a user would (calibrating first) and score it against its
    truth; with ``open_set``, each single-effect dataset again with its candidate switched off (``--without``:
    leave-one-family-out). The tables overall and per split (``splits``: name -> split; ``only``: that split
    alone). ``on_done(doc)`` after each dataset: the results so far (a long benchmark keeps what it did)."""
    if open_set and not open_set_supported():
        raise RuntimeError("the open-set runs need diagnose(..., without=...) (issue 41)")
    splits = splits or {}
    available = frozenset(CANDIDATES)
    rows = []
    for truth_file in sorted(folder.glob("*.truth.json")):
        data = folder / truth_file.name.removesuffix(".truth.json")
        split = splits.get(data.name, "unlisted")
        if not data.is_dir() or (only is not None and split != only):
            continue
        rows.append(labelled_row(data, json.loads(truth_file.read_text()), split, workers, open_set, available))
        if on_row is not None:
            row = rows[-1]
            on_row({k: row.get(k) for k in ("dataset", "split", "effect", "cause", "extension", "wall_s",
                                            "open_wall_s")}
                   | {"answer": row["score"]["answer"], "open_set": row["score"].get("open_set", {}).get("outcome"),
                      "p": {n: round(t["p"], 3) for n, t in row["tests"].items()}, "recovery": row.get("recovery")})
        if on_done is not None:
            on_done(labelled_document(rows, folder, available))
    return labelled_document(rows, folder, available)


def labelled_document(rows: list[dict], folder: Path,
                      available: frozenset[str] = frozenset(CANDIDATES)) -> dict[str, Any]:
    """Every dataset's row and the tables (:func:`fishfmu.analysis.truth_score.summarise_by_split`): singles'
    confusion, no-effect false alarms, compounds' two measures, the open set, times; overall and per split."""
    return {"runs": rows, "candidates": sorted(available), **summarise_by_split(rows), "folder": str(folder),
            "target_s_per_ten_runs": TARGET_S}


def _kept_runs(path: Path) -> tuple[list[dict], list[str]]:
    """The rows of one ``--labelled`` results file, and the candidates its run had, checked."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot read it as JSON ({exc})") from None
    runs = doc.get("runs") if isinstance(doc, dict) else None
    if not isinstance(runs, list):
        raise InputError(f"{path}: not the results of `fishfmu bench diagnose --labelled` (no list of runs)")
    if "candidates" not in doc:
        raise InputError(f"{path}: has no candidates (results from before issue 41 cannot be scored again)")
    if not isinstance(doc["candidates"], list) or not all(isinstance(c, str) for c in doc["candidates"]):
        raise InputError(f"{path}: candidates is not a list of candidate names")
    for i, r in enumerate(runs):
        if not isinstance(r, dict) or not isinstance(r.get("dataset"), str) or not isinstance(r.get("truth"), dict):
            raise InputError(f"{path}: runs[{i}] has no dataset name and truth (results from before issue 41 cannot "
                             "be scored again)")
        if not isinstance(r.get("diagnosis"), dict) and not isinstance(r.get("open_set_run"), dict):
            raise InputError(f"{path}: runs[{i}] ({r['dataset']}) has neither a diagnosis nor an open-set run")
    return runs, doc["candidates"]


def rescore(paths: list[Path]) -> dict[str, Any]:
    """The results of ``--labelled`` runs (their ``--json``, whole or partial) scored again from the truths and
    diagnoses each row kept, each with the candidates its run had: new tables without diagnosing anything again.

    Several files are merged in order, by dataset: a later row's diagnosis replaces an earlier one's, and its
    open-set run (leave-one-family-out) replaces an earlier one only where it has one, so a round diagnosed again
    without ``--open-set`` keeps the open-set runs measured before; a row with an open-set run alone (no
    diagnosis) adds it to the dataset's diagnosis of an earlier file."""
    merged: dict[str, dict] = {}
    for path in paths:
        runs, candidates = _kept_runs(path)
        for r in runs:
            r = r | {"candidates": r.get("candidates", candidates)}
            before = merged.get(r["dataset"], {})
            if "diagnosis" not in r:  # an open-set run alone: added to the dataset's diagnosis of an earlier file
                r = (before or {k: r[k] for k in ("dataset", "split", "truth", "candidates")}) | {
                    k: r[k] for k in ("open_set_run", "open_wall_s") if k in r}
            elif "open_set_run" not in r and "open_set_run" in before:
                r = r | {k: before[k] for k in ("open_set_run", "open_wall_s") if k in before}
            merged[r["dataset"]] = r
    rows = []
    for name, r in merged.items():
        if not isinstance(r.get("diagnosis"), dict):
            raise InputError(f"{name}: an open-set run without the dataset's own diagnosis in any of "
                             + ", ".join(map(str, paths)))
        scored = score(r["truth"], r["diagnosis"], frozenset(r["candidates"]), r.get("open_set_run"))
        rows.append(r | {"score": scored, "correct": is_right(scored)})
    every = sorted({c for r in rows for c in r["candidates"]})
    return labelled_document(rows, Path(str(paths[-1])), frozenset(every))


def extension_by_cause(rows: list[dict]) -> dict[str, dict[str, int]]:
    """Issue 40's two measures per cause, over the single-effect datasets whose cause was named right: the
    extension confirmed on held-out runs, and its strength within x1.5 of the truth (where the truth has one)."""
    out: dict[str, dict[str, int]] = {}
    for r in rows:
        if r.get("score", {}).get("single") != "right":
            continue
        c = out.setdefault(r["score"]["named"][0], {"named": 0, "confirmed": 0, "recovered": 0, "within": 0})
        c["named"] += 1
        c["confirmed"] += r.get("extension") == "confirmed"
        if rec := r.get("recovery"):
            c["recovered"] += 1
            c["within"] += bool(rec.get("within"))
    return dict(sorted(out.items()))


def _pct(rate: float | None) -> str:
    return "-" if rate is None else f"{rate:.0%}"


def part_lines(name: str, part: dict[str, Any]) -> list[str]:
    """One split's tables, as lines for the console."""
    s, n, c, o = part["singles"], part["no_effect"], part["compounds"], part["open_set"]
    lines = [f"-- {name}: {part['datasets']} datasets"]
    if s["n"]:
        confusion = pd.DataFrame(s["confusion"]).T.fillna(0).astype(int)
        lines += [f"singles (truth's candidate \\ named, or the answer): right {s['right']} of {s['n']} "
                  f"({_pct(s['right_rate'])}), wrong {s['wrong']}, none {s['none']}", confusion.to_string()]
    if n["n"]:
        lines.append(f"no effect: false alarms {n['false_alarms']} of {n['n']} ({_pct(n['false_alarm_rate'])}; "
                     f"named a cause {n['named']}, unexplained {n['unexplained']}, fits {n['fits']})")
    if c["n"]:
        lines.append(f"compounds: all causes named {c['all_named']} of {c['n']} ({_pct(c['all_named_rate'])}); "
                     f"at least one right and none wrong {c['one_right_none_wrong']} of {c['n']} "
                     f"({_pct(c['one_right_none_wrong_rate'])})")
    if o["n"]:
        lines.append(f"open set (family's candidate off or none): unexplained and located right {o['located']} of "
                     f"{o['n']} ({_pct(o['located_rate'])}; following its covariate {o['following']}), located "
                     f"elsewhere {o['elsewhere']}, fits {o['fits']}, a wrong cause {o['wrong']} "
                     f"({_pct(o['wrong_rate'])})")
        lines += [f"   {fam}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
                  for fam, counts in o["by_family"].items()]
    for key, what in (("wall_s", "diagnose"), ("open_wall_s", "open-set re-run")):
        t = part.get(key)
        if t:
            lines.append(f"time per dataset ({what}): mean {t['mean']:.0f} s, median {t['median']:.0f} s, max "
                         f"{t['max']:.0f} s over {t['n']} (target {TARGET_S:.0f} s per ten-run dataset)")
    return lines


def summary(doc: dict[str, Any]) -> list[str]:
    """What the benchmark found, as lines for the console."""
    if "all" not in doc:  # the synthetic benchmark (--seeds)
        return _synthetic_summary(doc)
    splits = doc.get("splits", {})
    lines = part_lines("all", doc["all"])
    if len(splits) > 1:
        for name, part in sorted(splits.items()):
            lines += part_lines(name, part)
    lines += answer_lines(doc.get("runs", []))
    if by_cause := extension_by_cause(doc.get("runs", [])):
        lines.append("-- per cause, of the singles named right: the extension confirmed on held-out runs; the strength "
                     f"within x{RECOVERED_WITHIN:g} of the truth")
        lines += [f"{cause}: confirmed {c['confirmed']} of {c['named']}; within {c['within']} of {c['recovered']}"
                  for cause, c in by_cause.items()]
    rows = [r for r in doc.get("runs", []) if r.get("fit") is not None and r.get("recovery")]
    if rows:
        lines.append("-- the named cause's extension against the base on held-out runs, its strength against the truth")
        for r in rows:
            rec = r["recovery"]
            lo, hi = r["fit"]["ci95"]
            lines.append(f"{r['dataset']}: {r['effect']} extension {r.get('extension', '?')}, held-out gain "
                         f"{r['fit']['gain']:.1%} [{lo:.1%}, {hi:.1%}]; {rec['term']} fitted {rec['fitted']:.3g}, "
                         f"truth {rec['truth']:.3g} (x{rec['ratio']:.2f}, "
                         + ("within" if rec["within"] else "outside") + f" x{RECOVERED_WITHIN:g})")
    return lines


def answer_lines(rows: list[dict]) -> list[str]:
    """Each compound's and open-set run's answer: what was named, and where the unexplained findings are."""
    lines = []
    for r in rows:
        sc = r["score"]
        if sc["kind"] == "compound":
            lines.append(f"{r['dataset']} ({r['split']}): compound, named {sc['label']}")
        if "open_set" in sc:
            o = sc["open_set"]
            without = "+".join(o["left_out"]) or "a candidate"
            wrong = f" {'+'.join(o['wrong'])}" if o["wrong"] else ""
            where = f" at {', '.join(o['where'])}" if o["where"] else ""
            lines.append(f"{r['dataset']} ({r['split']}): open set without {without}: {o['outcome']}, "
                         f"{o['answer']}{wrong}{where}")
    return ["-- compounds and open-set runs, one by one"] + lines if lines else []


def _synthetic_summary(doc: dict[str, Any]) -> list[str]:
    if not doc.get("confusion"):
        return []
    confusion = pd.DataFrame(doc["confusion"]).fillna(0).astype(int)
    return ["-- all", confusion.to_string(), pd.Series(doc["accuracy"], name="accuracy").to_string(),
            f"overall: {doc['overall']:.0%}"]
