"""A script calling fishfmu.commands gets what the command line gets: the same files, byte for byte,
the same refusals before anything is written."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from plant.errors import InputError

from fishfmu import commands

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
SHORT = {"fish.count": 3, "run.duration_s": 6.0, "fish.first_drop_s": 3.0, "run.stop_when_clear": False}


def test_commands_run_writes_what_fishfmu_run_writes(tmp_path: Path) -> None:
    done = commands.run(PAPER, tmp_path / "script", SHORT, report=False)
    assert done.out_dir == tmp_path / "script" and done.result.status == "ok" and done.stop_exit_code is None
    written = json.loads((done.out_dir / "kpis.json").read_text())
    assert written["fish_in"] == done.result.kpis["fish_in"] == 3
    sets = [a for k, v in SHORT.items() for a in ("--set", f"{k}={str(v).lower()}")]
    cli = subprocess.run([sys.executable, "-m", "fishfmu.cli", "run", str(PAPER), "--out", str(tmp_path / "cli"),
                          "--no-report", *sets], capture_output=True, text=True, cwd=tmp_path,
                         env={**os.environ, "CI": "1"})
    assert cli.returncode in (0, 1), cli.stderr  # 1: the paper's [expect] bounds on a 6 s run
    for name in ("kpis.json", "signals.csv", "run/runs/paper_dump/tracks.csv", "run/runs/paper_dump/belts.csv"):
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "script" / name).read_bytes(), name


def test_commands_refuse_bad_input_before_writing(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="fmu\\[0\\].parameters.no_such_parameter"):
        commands.run(PAPER, tmp_path / "out", {**SHORT, "fmu[0].parameters.no_such_parameter": 1.0})
    assert not (tmp_path / "out").exists()
    with pytest.raises(InputError, match="exactly one FMU"):
        commands.build_fmus([], tmp_path / "fmus", {"gear_ratio": 8.0})
    assert not (tmp_path / "fmus").exists()
