"""Leave-one-family-out runs made by hand, as benchmark rows that `fishfmu bench diagnose --rescore` merges.

`fishfmu bench diagnose --open-set` diagnoses a dataset twice (whole, then with its family's candidate left out).
Where the whole diagnosis is already kept in earlier results, the second alone can be run by hand:

    fishfmu diagnose BENCH/NAME --out OUT/NAME --workers 2 --without CANDIDATE

This reads each OUT/NAME/diagnosis.json (what was left out is in it), takes the truth from BENCH/NAME.truth.json and
the split from the recipe, and writes rows holding only the open-set run:

    python docs/diagnose-bench/open_runs.py --labelled BENCH --recipe docs/diagnose-bench/recipe.toml \
        --json open.json OUT/NAME ...
    fishfmu bench diagnose --rescore earlier.json --rescore open.json --json merged.json
"""
import argparse
import json
from pathlib import Path

from fishfmu.analysis.candidates import CANDIDATES
from fishfmu.bench.diagnose import KEPT, read_splits


def open_row(out: Path, labelled: Path, splits: dict[str, str]) -> dict:
    name = out.name
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    truth = json.loads((labelled / f"{name}.truth.json").read_text())
    if not diagnosis.get("left_out"):
        raise SystemExit(f"{out / 'diagnosis.json'}: no candidate was left out (not an open-set run)")
    return {"dataset": name, "split": splits.get(name, "unlisted"),
            "truth": {k: truth[k] for k in ("effect", "effects", "magnitude") if k in truth},
            "open_set_run": {"left_out": list(diagnosis["left_out"]),
                             "diagnosis": {k: diagnosis[k] for k in KEPT if k in diagnosis}}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outs", nargs="+", type=Path, help="diagnose's output folders, each named as its dataset")
    ap.add_argument("--labelled", type=Path, required=True, help="the folder of the datasets and their truth files")
    ap.add_argument("--recipe", type=Path, default=None)
    ap.add_argument("--json", type=Path, required=True)
    a = ap.parse_args()
    splits = read_splits(a.recipe)
    doc = {"runs": [open_row(o, a.labelled, splits) for o in a.outs], "candidates": sorted(CANDIDATES)}
    a.json.write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
