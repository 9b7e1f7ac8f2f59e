"""Make the diagnose benchmark's datasets from recipe.toml with the independent simulator.

    python docs/diagnose-bench/generate.py --linesim ../shared/linesim --python /tmp/linesim-venv/bin/python \
        --out /tmp/diag-bench [--only NAME ...] [--runs 10] [--jobs 2]

Each dataset goes to OUT/NAME with OUT/NAME.truth.json beside it (what `fishfmu bench diagnose
--labelled OUT` reads). A dataset whose truth file exists is kept. This calls linesim's own
command line: fishfmu never imports or runs the simulator.
"""
import argparse
import subprocess
import sys
import tomllib
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--linesim", type=Path, required=True)
    ap.add_argument("--python", default=sys.executable, help="a Python with linesim's requirements")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--recipe", type=Path, default=Path(__file__).with_name("recipe.toml"))
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--split", choices=["dev", "heldout"], default=None)
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--fish", type=int, default=18)
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    recipe = tomllib.loads(a.recipe.read_text())["dataset"]
    a.out.mkdir(parents=True, exist_ok=True)
    for d in recipe:
        if (a.only and d["name"] not in a.only) or (a.split and d["split"] != a.split):
            continue
        if (a.out / f"{d['name']}.truth.json").exists():
            continue
        cmd = [a.python, str(a.linesim / "gen.py"), "--effect", d["effect"], "--seed", str(d["seed"]),
               "--runs", str(a.runs), "--fish", str(a.fish), "--design", "campaign", "--jobs", str(a.jobs),
               "--out", str(a.out / d["name"])]
        for k, v in d["flags"].items():
            cmd += [f"--{k}", str(v)]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
