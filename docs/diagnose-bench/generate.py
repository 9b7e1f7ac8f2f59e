"""Make the diagnose benchmark's datasets from recipe.toml with the independent simulator.

    python docs/diagnose-bench/generate.py --linesim ../shared/linesim --python LINESIM_PYTHON \
        --out BENCH [--split dev|heldout] [--only NAME ...] [--round 1|2|3|4|5] [--runs 10] [--jobs 2] [--dry-run]

Each dataset goes to OUT/NAME with OUT/NAME.truth.json beside it (what `fishfmu bench diagnose --labelled OUT`
reads). A dataset whose truth file exists is kept (a stopped generation goes on where it was). A compound's
effect is passed as linesim spells it (``--effect mucus+drive_droop``) with every part's flags. This calls
linesim's own command line: fishfmu never imports or runs the simulator. Commands for the lead: README.md here.
"""
import argparse
import subprocess
import sys
import tomllib
from pathlib import Path

ROUND1, ROUND2, ROUND3, ROUND4 = 30, 20, 6, 8
"""The recipe's first 30 entries are round 1 (2026-11-26), the next 20 round 2 (issue 41), the next 6 round 3
(2026-11-30, all held out), the next 8 round 4 (2026-11-30, all held out), the rest round 5 (the same evening, all
held out)."""


def selected(recipe: list[dict], only=None, split=None, round_=None) -> list[dict]:
    """The recipe's entries chosen by name, split and round (each None: all)."""
    r3 = ROUND1 + ROUND2
    r4 = r3 + ROUND3
    rounds = {1: recipe[:ROUND1], 2: recipe[ROUND1:r3], 3: recipe[r3:r4], 4: recipe[r4:r4 + ROUND4],
              5: recipe[r4 + ROUND4:]}
    pool = rounds[round_] if round_ else recipe
    return [d for d in pool if (not only or d["name"] in only) and (not split or d["split"] == split)]


def command(d: dict, linesim: Path, python: str, out: Path, runs: int = 10, fish: int = 18, jobs: int = 1) -> list[str]:
    """linesim's command line that makes dataset ``d`` (a recipe entry) in OUT/NAME."""
    cmd = [python, str(linesim / "gen.py"), "--effect", d["effect"], "--seed", str(d["seed"]), "--runs", str(runs),
           "--fish", str(fish), "--design", "campaign", "--jobs", str(jobs), "--out", str(out / d["name"])]
    for k, v in d["flags"].items():
        cmd += [f"--{k}", str(v)]
    return cmd


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--linesim", type=Path, required=True)
    ap.add_argument("--python", default=sys.executable, help="a Python with linesim's requirements")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--recipe", type=Path, default=Path(__file__).with_name("recipe.toml"))
    ap.add_argument("--only", nargs="*", default=None, help="these datasets (names) only")
    ap.add_argument("--split", choices=["dev", "heldout"], default=None)
    ap.add_argument("--round", dest="round_", type=int, choices=[1, 2, 3, 4, 5], default=None,
                    help="1: the first 30 (2026-11-26); 2: issue 41's; 3: 2026-11-30's, all held out")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--fish", type=int, default=18)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--dry-run", action="store_true", help="print the commands, make nothing")
    a = ap.parse_args()
    recipe = tomllib.loads(a.recipe.read_text())["dataset"]
    unknown = sorted(set(a.only or ()) - {d["name"] for d in recipe})
    if unknown:
        sys.exit(f"{a.recipe}: no dataset named {', '.join(unknown)}")
    for d in selected(recipe, a.only, a.split, a.round_):
        if (a.out / f"{d['name']}.truth.json").exists():
            continue
        cmd = command(d, a.linesim, a.python, a.out, a.runs, a.fish, a.jobs)
        print(" ".join(cmd), flush=True)
        if not a.dry_run:
            a.out.mkdir(parents=True, exist_ok=True)
            subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
