"""Limits on what input can make fishfmu allocate or run (issue 13): each is bad input (exit 2,
``InputError``) naming the limit, found before anything is allocated or written."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from plant.errors import InputError
from plant.validation import MAX_CSV_BYTES, MAX_TOML_BYTES, MAX_TOML_DEPTH, read_regular_file, read_toml

from fishfmu.scenario.schema import load_scenario
from fishfmu.batch.sweep_spec import MAX_RUNS, check_size, make_spec, parse_param

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "paper_dump.toml"


def fishfmu(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], cwd=cwd, capture_output=True, text=True,
                          env={**os.environ, "CI": "1", "PYTHONPATH": str(ROOT)}, timeout=60)


@pytest.mark.parametrize("text", [
    "a = " + "[" * 10_000 + "]" * 10_000,                               # arrays in arrays
    "a = " + "{b = " * 5_000 + "1" + "}" * 5_000,                       # inline tables in inline tables
    "[" + ".".join(["a"] * 10_000) + "]\nx = 1\n",                      # a table header 10 000 keys deep
    "".join("[[" + ".".join(["a"] * i) + "]]\n" for i in range(1, 60)),  # arrays of tables in arrays of tables
])
def test_deeply_nested_toml_is_refused_naming_the_limit(tmp_path, text):
    path = tmp_path / "deep.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=f"nest.*{MAX_TOML_DEPTH} levels") as info:
        load_scenario(path)
    assert info.value.file == path


def test_a_toml_file_within_the_depth_limit_is_read(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text("a = " + "[" * (MAX_TOML_DEPTH - 1) + "]" * (MAX_TOML_DEPTH - 1))
    assert "a" in read_toml(path)


def test_a_toml_file_over_10_mb_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big.toml"
    with open(path, "wb") as fh:
        fh.truncate(MAX_TOML_BYTES + 1)  # sparse: no 10 MB written
    with pytest.raises(InputError, match="at most 10 MB"):
        read_toml(path)


def test_a_dataset_csv_over_the_limit_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "tracks.csv"
    with open(path, "wb") as fh:
        fh.truncate(MAX_CSV_BYTES + 1)
    with pytest.raises(InputError, match="at most 512 MB"):
        read_regular_file(path, MAX_CSV_BYTES, "dataset CSV file")
    from plant.contract.measured import _read_text
    with pytest.raises(InputError, match="at most 512 MB"):
        _read_text(path)


def test_a_symlink_loop_as_scenario_is_bad_input(tmp_path):
    (tmp_path / "a.toml").symlink_to(tmp_path / "b.toml")
    (tmp_path / "b.toml").symlink_to(tmp_path / "a.toml")
    with pytest.raises(InputError, match="symbolic links") as info:
        load_scenario(tmp_path / "a.toml")
    assert info.value.file == tmp_path / "a.toml"


def test_a_symlink_loop_as_out_folder_is_bad_input_naming_it(tmp_path):
    (tmp_path / "o1").symlink_to(tmp_path / "o2")
    (tmp_path / "o2").symlink_to(tmp_path / "o1")
    p = fishfmu("run", str(SCENARIO), "--out", str(tmp_path / "o1"), "--set", "fish.count=1", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert "o1" in p.stderr and "internal error" not in p.stderr and len(p.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("param", ["fish.count=0:1:1000000000", "fish.count=1:2:" + "9" * 5000])
def test_a_huge_range_is_refused_before_it_is_allocated(param):
    with pytest.raises(InputError, match=f"at most {MAX_RUNS} values"):
        parse_param(param)


def test_points_times_seeds_is_capped():
    check_size(1000, 100)  # exactly the limit
    with pytest.raises(InputError, match=f"at most {MAX_RUNS} runs"):
        check_size(1000, 101)
    with pytest.raises(InputError, match=f"at most {MAX_RUNS} runs"):
        make_spec(SCENARIO, {"fish.count": list(range(1, 1001))}, 101)
    with pytest.raises(InputError, match=f"at most {MAX_RUNS} runs"):
        make_spec(SCENARIO, {}, 1_000_000_000)  # run --seeds 1e9: refused before the seeds are listed


def test_seeds_past_the_largest_seed_are_refused_before_the_sweep_starts():
    make_spec(SCENARIO, {"fish.count": [2]}, 1, {"run.seed": 2**32 - 1})  # the largest seed itself
    with pytest.raises(InputError, match="past the largest seed"):
        make_spec(SCENARIO, {"fish.count": [2]}, 2, {"run.seed": 2**32 - 1})


@pytest.mark.parametrize("param", ["fish.length_mean_m=nan,0.5", "fish.length_mean_m=0.5,inf",
                                   "fish.length_mean_m=-inf", "fmu[0].parameters.speed_2=[0.4, nan]",
                                   "fish.length_mean_m=1e999:1:3"])
def test_nan_or_inf_in_a_sweep_value_is_refused_naming_the_param(param):
    with pytest.raises(InputError, match="NaN|inf") as info:
        parse_param(param)
    assert param.split("=")[0] in str(info.value)


def test_the_sweep_command_refuses_a_billion_points_quickly_and_writes_nothing(tmp_path):
    p = fishfmu("sweep", str(SCENARIO), "--out", str(tmp_path / "sw"), "--param", "fish.count=0:1:1000000000",
                cwd=tmp_path)
    assert p.returncode == 2 and f"at most {MAX_RUNS} values" in p.stderr, p.stderr
    assert not (tmp_path / "sw").exists()


def test_simulated_time_is_bounded_to_a_day():
    with pytest.raises(InputError, match="86400"):
        load_scenario(SCENARIO, {"run.duration_s": 1e9})


# ---------------------------------------------------------------- camera logs: what fishfmu writes it reads back

REJECT_DOUBLES = Path(__file__).parents[1] / "scenarios" / "reject_doubles.toml"


def cameras(n: int, rate_hz: float) -> list[dict]:
    return [{"id": f"cam{i}", "x_start_m": 1.0, "x_end_m": 3.0, "rate_hz": rate_hz} for i in range(n)]


def test_64_cameras_at_200_hz_are_refused_before_the_run_naming_the_key():
    """Issue 39: 64 cameras at 200 Hz logged a 557 MB detections.csv in 55 s that fishfmu's own compare refused."""
    with pytest.raises(InputError) as info:
        load_scenario(REJECT_DOUBLES, {"line.cameras": cameras(64, 200.0), "run.duration_s": 55.0})
    assert info.value.where == "line.cameras"
    assert "detections.csv" in str(info.value) and "at most 512 MB" in str(info.value)


def test_the_largest_camera_log_a_scenario_may_ask_for_is_one_fishfmu_reads():
    """By arithmetic on the limits: the most fish one 200 Hz camera may log over ten minutes is loaded, one more is
    refused, and the bound on its file (every fish in view in every frame, every number as long as pandas writes
    one) is within the reader's limit."""
    from plant.contract.log_values import detections_bytes_bound, detection_row_bytes
    cam = cameras(1, 200.0)
    frames = 200 * 600 + 1
    most = (MAX_CSV_BYTES - 100) // (frames * detection_row_bytes("cam0"))
    sc = load_scenario(REJECT_DOUBLES, {"line.cameras": cam, "run.duration_s": 600.0, "fish.count": int(most)})
    assert detections_bytes_bound(sc.line.cameras, 600.0, int(most)) <= MAX_CSV_BYTES
    with pytest.raises(InputError, match="detections.csv"):
        load_scenario(REJECT_DOUBLES, {"line.cameras": cam, "run.duration_s": 600.0, "fish.count": int(most) + 1})
    assert most == 21  # 120 001 frames x 21 fish x 205 bytes = 493 MiB (at 30 Hz: 145 fish)


def test_no_written_detection_row_is_longer_than_the_bound_assumes():
    """The bound's row: eight numbers of at most 24 characters each as the writer (pandas' to_csv, as
    plant.contract.measured.write_run calls it) writes the longest floats, the longest id, a huge track number."""
    import pandas as pd
    from plant.contract.log_values import detection_row_bytes
    camera_id = "c" * 64
    worst = -1.2345678901234567e-308
    df = pd.DataFrame({"t_s": [worst], "camera_id": [camera_id], "track": [2**62], "x_back_m": [worst],
                       "x_front_m": [worst], "y_m": [worst], "length_m": [worst], "heading": [-1.0], "double": [1.0]})
    df = pd.concat([df, df.assign(track=[-(2**63)], heading=[-1], double=[1])])
    rows = df.to_csv(index=False, na_rep="").encode().splitlines(keepends=True)[1:]
    assert max(len(r) for r in rows) <= detection_row_bytes(camera_id)
