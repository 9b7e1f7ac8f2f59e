"""What happens around the dataset readers' checks (issue 13): a re-simulation that fails anyway gives
exit 3 naming the run; a corrupt poses.npz is bad input; tables whose dtype pandas would otherwise
guess (an empty table in a concatenation) stay boolean/float.

The physically implausible datasets themselves (drops outside the line, a 5 m fish, belts at 1e6 m/s,
Latin-1 text, trailing commas, ...) are cases of ``BAD_INPUTS`` in tests/test_measured.py, run through
the reader there and through the command (exit 2, one line, nothing written) in tests/test_bad_input.py.
"""

from __future__ import annotations

import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.errors import InputError, SimulationError
from plant.contract.measured import read_dataset, write_dataset
from plant.contract.plausibility import MAX_RESIM_S
from plant.sim.state import FishStatus

from tests.test_measured import small_dataset  # noqa: F401 (a fixture, used by name)


def fishfmu(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, *args: str) -> tuple[int, str]:
    """``fishfmu ARGS`` in this process: (exit code, stderr)."""
    from fishfmu.cli import main
    monkeypatch.setattr(sys, "argv", ["fishfmu", *args])
    with pytest.raises(SystemExit) as done:
        main()
    return done.value.code, capsys.readouterr().err


def fail_run(monkeypatch: pytest.MonkeyPatch, run_id: str) -> None:
    """Re-simulating ``run_id`` blows up (in this process: the commands run with --workers 1)."""
    import fishfmu.analysis.resim
    real = fishfmu.analysis.resim.resimulate

    def resimulate(line, run, *args, **kwargs):
        if run.id == run_id:
            raise SimulationError("numerical blow-up: fish 'f02' moves at 31.0 m/s", 2.35)
        return real(line, run, *args, **kwargs)

    monkeypatch.setattr(fishfmu.analysis.resim, "resimulate", resimulate)


# ------------------------------------------------------------------------- a failed re-simulation
def test_compare_exits_3_naming_the_failed_run_after_writing_the_others(small_dataset: Path, tmp_path: Path,  # noqa: F811
                                                                        capsys, monkeypatch):
    fail_run(monkeypatch, "r2")
    out = tmp_path / "out"
    code, err = fishfmu(capsys, monkeypatch, "compare", str(small_dataset), "--out", str(out), "--workers", "1")
    lines = err.strip().splitlines()
    assert code == 3, err
    assert len(lines) == 1 and lines[0].startswith(
        "simulation failed: run 'r2': at t = 2.350 s: numerical blow-up: fish 'f02' moves at 31.0 m/s"), err
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "failed" and info["error"].startswith("run 'r2': at t = 2.350 s")
    assert list(json.loads((out / "compare.json").read_text())["failed"]) == ["r2"]
    kpis = pd.read_csv(out / "kpis.csv")
    assert set(kpis["run_id"]) == {"r1"}  # the run that did re-simulate is compared and written
    assert (out / "report.html").is_file()


def test_diagnose_stops_after_the_baseline_naming_the_failed_run(small_dataset: Path, tmp_path: Path,  # noqa: F811
                                                                 capsys, monkeypatch):
    fail_run(monkeypatch, "r1")
    out = tmp_path / "out"
    code, err = fishfmu(capsys, monkeypatch, "diagnose", str(small_dataset), "--out", str(out), "--workers", "1")
    assert code == 3, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("simulation failed: run 'r1': at t = 2.350 s: numerical blow-up"), err
    assert "evidence:" not in err  # stopped before the evidence and the fits
    info = json.loads((out / "run_info.json").read_text())
    assert info["status"] == "failed" and "run 'r1'" in info["error"]


def test_compare_dataset_reports_the_failure_through_the_python_api(small_dataset: Path, monkeypatch):  # noqa: F811
    from fishfmu.analysis.compare import compare_dataset
    fail_run(monkeypatch, "r1")
    ds = read_dataset(small_dataset)
    ds.runs = ds.runs[:1]  # only the failing run: nothing is simulated
    c = compare_dataset(ds, workers=1)
    assert c.failure() == "run 'r1': at t = 2.350 s: numerical blow-up: fish 'f02' moves at 31.0 m/s"
    assert c.kpis.empty and c.kpis["measured"].dtype == float


def test_resimulate_refuses_a_run_made_in_code_beyond_the_limits(small_dataset: Path):  # noqa: F811
    from fishfmu.analysis.resim import resimulate
    ds = read_dataset(small_dataset)
    run = ds.run("r1")
    with pytest.raises(InputError, match=rf"run 'r1': .* more than the limit of {MAX_RESIM_S:g} s"):
        resimulate(ds.line, run, duration_s=10 * MAX_RESIM_S)
    run.belts = run.belts[run.belts["conveyor_id"] != "c2"]
    with pytest.raises(InputError, match="run 'r1': no belt speeds logged for conveyor.* c2"):
        resimulate(ds.line, run)


# ------------------------------------------------------------------------- pandas dtypes
def test_belt_rows_concatenated_with_an_empty_table_keep_their_types():
    """pandas 3 keeps an empty table's object dtype in a concat: ``~`` on the 'crowded' column then gave
    -1/-2 (bitwise on Python bools) and a KeyError (issue 13). The tables are typed now."""
    from fishfmu.analysis.residuals import BELT_RESIDUAL_DTYPES, alone, concat_typed, typed_frame
    rng = np.random.default_rng(0)
    rows = typed_frame([{"run_id": f"r{k % 3}", "fish_id": f"f{k}", "belt": 1, "conveyor_id": "c2", "t_start_s": 1.0,
                         "t_end_s": 2.0, "offset_m": 0.0, "lag_m": float(rng.normal(0.0, 0.01)),
                         "heading": float(rng.choice([-1.0, 1.0])), "hours_post_mortem": 6.0 * (k % 3 + 1),
                         "length_m": 0.6, "crowded": k % 4 == 0, "n_samples": 10} for k in range(12)],
                       BELT_RESIDUAL_DTYPES)
    empty = typed_frame([], BELT_RESIDUAL_DTYPES)  # a run whose fish never lay alone on a belt
    assert empty["crowded"].dtype == bool and empty["lag_m"].dtype == float
    both = concat_typed([empty, rows], BELT_RESIDUAL_DTYPES)
    assert both["crowded"].dtype == bool and len(alone(both)) == 9
    untyped = pd.concat([pd.DataFrame(columns=list(BELT_RESIDUAL_DTYPES)), rows], ignore_index=True)
    with pytest.raises(TypeError, match="'crowded' has dtype object"):  # a bug, said as one, never -1s
        alone(untyped)


# ------------------------------------------------------------------------- poses.npz
def _run_dir(small_dataset: Path, tmp_path: Path) -> Path:  # noqa: F811
    """A ``fishfmu run --replay`` folder as far as replay reads it: run/ and poses.npz (valid, 2 frames)."""
    ds = read_dataset(small_dataset)
    ds.runs = ds.runs[:1]
    run_dir = tmp_path / "run_out"
    write_dataset(ds, run_dir / "run")
    n_fish, n_b = 3, 15
    np.savez(run_dir / "poses.npz", t_s=np.array([0.0, 0.04]), pos=np.zeros((2, n_b, 3), np.float32),
             quat=np.tile(np.array([1, 0, 0, 0], np.float32), (2, n_b, 1)),
             status=np.full((2, n_fish), FishStatus.ON_LINE, np.int8),
             fish_id=np.array(["f01", "f02", "f03"]), body_fish=np.repeat(np.arange(n_fish), 5).astype(np.int32),
             section_body=np.arange(n_b, dtype=np.int32), section_x=np.zeros(n_b, np.float32),
             section_half_height=np.full(n_b, 0.05, np.float32), section_half_width=np.full(n_b, 0.03, np.float32))
    return run_dir


def _rewrite(path: Path, **changes) -> None:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays.update(changes)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})


CORRUPT_POSES = {
    "truncated": (lambda f: f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2]), "not a readable pose record"),
    "not a zip": (lambda f: f.write_bytes(b"PK\x03\x04 garbage" * 10), "not a readable pose record"),
    "text": (lambda f: f.write_text("t_s,pos\n1,2\n"), "not a readable pose record"),
    "an array missing": (lambda f: _rewrite(f, quat=None), "no array quat"),
    "shapes disagree": (lambda f: _rewrite(f, pos=np.zeros((3, 15, 3))), "array pos has shape (3, 15, 3)"),
    "a body of no fish": (lambda f: _rewrite(f, body_fish=np.full(15, 7, np.int32)), "body_fish names a fish"),
    "NaN pose": (lambda f: _rewrite(f, t_s=np.array([0.0, np.nan])), "t_s holds a value that is not a finite"),
    "pickled objects": (lambda f: _rewrite(f, fish_id=np.array([{"a": 1}] * 3, dtype=object)),
                        "not a readable pose record"),
}


@pytest.mark.parametrize("case", list(CORRUPT_POSES))
def test_a_corrupt_poses_npz_is_bad_input_naming_the_file(case: str, small_dataset: Path, tmp_path: Path):  # noqa: F811
    from fishfmu.output.replay import read_poses, scene
    run_dir = _run_dir(small_dataset, tmp_path)
    read_poses(run_dir / "poses.npz")  # the valid one reads
    corrupt, expected = CORRUPT_POSES[case]
    corrupt(run_dir / "poses.npz")
    with pytest.raises(InputError) as info:
        scene(run_dir)
    assert str(info.value).startswith(f"{run_dir / 'poses.npz'}: ") and expected in str(info.value), str(info.value)


def test_replay_of_a_corrupt_poses_npz_exits_2(small_dataset: Path, tmp_path: Path, capsys, monkeypatch):  # noqa: F811
    run_dir = _run_dir(small_dataset, tmp_path)
    zipfile.ZipFile(run_dir / "poses.npz", "w").close()  # an empty archive: no arrays
    code, err = fishfmu(capsys, monkeypatch, "replay", str(run_dir))
    assert code == 2 and err.startswith(f"error: {run_dir / 'poses.npz'}: not a pose record: no array t_s"), err
    assert not (run_dir / "replay.html").exists()


# ------------------------------------------------------------------------- CSV text
def test_quoted_crlf_csv_reads_and_a_trailing_comma_in_it_names_the_row(tmp_path: Path):
    from plant.contract.measured import PHOTOEYES, read_table
    path = tmp_path / "photoeyes.csv"
    path.write_bytes(b'\xef\xbb\xbfsensor_id,t_on_s,t_off_s\r\n"pe_in",1.2,2.4\r\n\r\n"pe,out",8.0,9.0\r\n')
    df = read_table(path, PHOTOEYES)
    assert list(df["sensor_id"]) == ["pe_in", "pe,out"] and list(df.index + 2) == [2, 4]
    path.write_bytes(b'sensor_id,t_on_s,t_off_s\r\n"pe_in",1.2,2.4\r\n\r\n"pe_out",8.0,9.0,\r\n')
    with pytest.raises(InputError, match=r"photoeyes\.csv: row 4: 4 fields, but the header has 3; a trailing comma"):
        read_table(path, PHOTOEYES)
