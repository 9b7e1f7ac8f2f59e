"""Determinism: the same scenario and seed give byte-identical kpis.json and run files, across two
runs (two processes with different hash seeds) and between FMUs in worker processes and in-process.

``run_info.json`` holds the wall times and is left out; ``scenario.resolved.toml`` differs between
the modes only in ``fmu_process`` itself.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fishfmu.output.run_folder import prepare_out_dir, write_outputs
from fishfmu.cosim.runner import run_scenario
from fishfmu.scenario.keys import parse_value
from fishfmu.scenario.schema import load_scenario

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
# three fish dropped onto the running infeed, the first two reach its photo-eye
SHORT = ["fish.count=3", "fish.first_drop_s=3.2", "run.duration_s=9.0", "run.stop_when_clear=false",
         "expect={}", "run.seed=7"]
COMPARED = ["kpis.json", "signals.csv", "scenario.resolved.toml", "run/dataset.toml",
            *(f"run/runs/paper_dump/{t}.csv" for t in ("fish", "tracks", "photoeyes", "belts"))]


def cli_run(out: Path, hash_seed: str, *extra: str) -> None:
    args = [a for s in SHORT + list(extra) for a in ("--set", s)]
    proc = subprocess.run([sys.executable, "-m", "fishfmu.cli", "run", str(PAPER), "--out", str(out), "--no-report",
                           *args], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, CI="true", PYTHONHASHSEED=hash_seed))
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def three_runs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("determinism")
    cli_run(root / "a", "1")
    cli_run(root / "worker", "2", 'run.fmu_process="worker"')
    sc = load_scenario(PAPER, {k: parse_value(v) for k, _, v in (s.partition("=") for s in SHORT)})
    here = prepare_out_dir(root / "here", overwrite=False)
    write_outputs(run_scenario(sc, PAPER), here, report=False)
    return {"a": root / "a", "worker": root / "worker", "here": root / "here"}


def test_the_run_is_not_trivial(three_runs) -> None:
    import json
    kpis = json.loads((three_runs["a"] / "kpis.json").read_text())
    assert kpis["status"] == "ok" and kpis["fish_in"] >= 2
    photoeyes = (three_runs["a"] / "run/runs/paper_dump/photoeyes.csv").read_text().splitlines()
    assert len(photoeyes) >= 2  # header and fish through the infeed's beam (the three dumped may pass as one)


@pytest.mark.parametrize("name", COMPARED)
def test_two_runs_give_the_same_bytes(three_runs, name: str) -> None:
    assert (three_runs["a"] / name).read_bytes() == (three_runs["here"] / name).read_bytes()


@pytest.mark.parametrize("name", COMPARED)
def test_worker_processes_give_the_same_bytes_as_in_process(three_runs, name: str) -> None:
    a = (three_runs["a"] / name).read_bytes()
    b = (three_runs["worker"] / name).read_bytes()
    if name == "scenario.resolved.toml":
        assert b'fmu_process = "worker"' in b
        b = b.replace(b'fmu_process = "worker"', b'fmu_process = "in-process"')
    assert a == b


def test_signals_csv_is_the_text_pandas_writes_with_ten_digits():
    """signals.csv is formatted column by column (faster than pandas' per-value formatter): the same bytes as
    ``to_csv(float_format="%.10g")`` for every kind of value a signal table holds, missing values empty."""
    import numpy as np
    import pandas as pd

    from fishfmu.output.run_folder import signals_csv

    rng = np.random.default_rng(3)
    frame = pd.DataFrame({"t_s": np.arange(50) * 0.01, "speed_mps": rng.normal(size=50) * 1e-7,
                          "force_n": rng.normal(size=50) * 1e6, "count": np.arange(50),
                          "reject": np.arange(50) % 3 == 0, "state": ["run, idle"] * 49 + ["x"]})
    frame.loc[[2, 7], "speed_mps"] = [np.nan, -0.0]
    frame.loc[[4, 9], "force_n"] = [np.inf, -np.inf]
    frame.loc[11, "t_s"] = 1.0 / 3.0
    assert signals_csv(frame) == frame.to_csv(index=False, float_format="%.10g")
    assert ",," in signals_csv(frame).splitlines()[3]  # the missing speed an empty cell
