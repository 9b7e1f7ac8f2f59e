"""Sweeps and Monte-Carlo KPIs: the same numbers on a cluster as one by one, failures recorded,
resuming, FMUs reaching workers that cannot build them, and the statistics by hand."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from plant.errors import InputError

from fishfmu.batch.engine import scalar_kpis
from fishfmu.scenario.schema import KPI_KEYS
from fishfmu.batch.stats import mean_ci, summarise, wilson_interval
from fishfmu.batch.sweep import run_sweep
from fishfmu.batch.sweep_spec import make_spec

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper_dump.toml"
# two fish dropped early on a line that starts quickly: they reach the outfeed within 12 s
SMALL = {"fish.count": 2, "run.duration_s": 12.0, "fish.first_drop_s": 1.0, "fmu[0].parameters.startup_delay": 0.3}
# nothing reaches the outfeed: cheap runs for bookkeeping tests
SHORT = {"fish.count": 2, "run.duration_s": 4.0, "fish.first_drop_s": 1.0}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory, builtin_fmus: dict[str, Path]):
    """Two worker processes that cannot build FMUs: an empty FMU cache of their own and a ``cmake``
    that only leaves a mark (a build would fail and be seen)."""
    from distributed import LocalCluster
    cache = tmp_path_factory.mktemp("worker_fmu_cache")
    fake_bin = tmp_path_factory.mktemp("fake_bin")
    marker = fake_bin / "cmake-was-called"
    (fake_bin / "cmake").write_text(f"#!/bin/sh\ntouch {marker}\nexit 1\n")
    (fake_bin / "cmake").chmod(0o755)
    env = {"FISHFMU_CACHE": str(cache), "PATH": f"{fake_bin}{os.pathsep}{os.environ.get('PATH', '')}"}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, env=env) as c:
        yield SimpleNamespace(address=c.scheduler_address, cache=cache, marker=marker)


def test_sweep_on_cluster_gives_the_same_kpis_as_runs_one_by_one(cluster, tmp_path: Path) -> None:
    from fishfmu.cosim.runner import run_scenario
    from fishfmu.scenario.schema import load_scenario
    params = {"fmu[0].parameters.speed_1": [0.35, 0.45], "fish.length_mean_m": [0.55, 0.65]}
    spec = make_spec(PAPER, params, 2, SMALL)
    res = run_sweep(spec, tmp_path / "sweep", scheduler=cluster.address)
    assert res.n_executed == 8 and len(res.runs) == 8 and (res.runs["status"] == "ok").all()
    assert res.runs["worker"].nunique() == 2  # both workers took part
    assert res.runs["throughput_time_s"].notna().any()  # fish did reach the outfeed
    for _, row in res.runs.iterrows():
        point = {k: row[k] for k in params}
        sc = load_scenario(PAPER, {**SMALL, **point, "run.seed": int(row["seed"])})
        alone = scalar_kpis(run_scenario(sc, PAPER).kpis)
        for k in KPI_KEYS:
            got = row[k]
            if alone[k] is None:
                assert got is None or math.isnan(got), k
            else:
                assert got == alone[k], (k, point, row["seed"])  # identical, not close
    assert len(res.summary) == 4 and (res.summary["n_ok"] == 2).all()
    for name in ("runs.parquet", "runs.csv", "summary.parquet", "summary.csv", "sweep.json"):
        assert (tmp_path / "sweep" / name).is_file()
    assert (tmp_path / "sweep" / "plots" / "singulation_rate__fmu_0_parameters_speed_1.png").is_file()


def test_failed_points_are_recorded_and_the_others_complete(cluster, tmp_path: Path) -> None:
    fixed = {**SHORT, "event": [{"t_s": 2.0, "target": "drive_c1.speed_setpoint", "action": "override",
                                 "value": 0.5}]}
    # speed_2 = -0.5 is outside the controller's declared range [0, 2]: caught before any run;
    # overriding the drive's setpoint with 5.0 (range [-2, 2]) makes the FMU fail during the run
    params = {"fmu[0].parameters.speed_2": [0.5, -0.5], "event[0].value": [0.5, 5.0]}
    res = run_sweep(make_spec(PAPER, params, 1, fixed), tmp_path / "sweep", scheduler=cluster.address, plots=False)
    runs = res.runs.set_index(["fmu[0].parameters.speed_2", "event[0].value"])
    assert res.n_executed == 2  # the two bad points were never sent to a worker
    assert runs.loc[(0.5, 0.5), "status"] == "ok"
    sim = runs.loc[(0.5, 5.0)]
    assert sim["status"] == "failed" and sim["error_kind"] == "simulation"
    assert "drive_c1" in sim["error"] and "t = 2.0" in sim["error"]
    for v in (0.5, 5.0):
        bad = runs.loc[(-0.5, v)]
        assert bad["status"] == "failed" and bad["error_kind"] == "input"
        assert "speed_2" in bad["error"] and "outside" in bad["error"]
    summary = res.summary.set_index(["fmu[0].parameters.speed_2", "event[0].value"])
    assert summary.loc[(0.5, 0.5), "n_ok"] == 1 and summary.loc[(0.5, 5.0), "n_failed"] == 1


def test_resume_skips_finished_runs(cluster, tmp_path: Path) -> None:
    spec = make_spec(PAPER, {"fish.length_mean_m": [0.55, 0.65]}, 2, SHORT)
    out = tmp_path / "sweep"
    first = run_sweep(spec, out, scheduler=cluster.address, max_runs=1, plots=False)  # as if stopped after one run
    assert (first.n_executed, len(first.runs)) == (1, 1)
    kept = next((out / "points").glob("*.json"))
    before = kept.read_bytes()
    second = run_sweep(spec, out, scheduler=cluster.address, plots=False)
    assert (second.n_executed, second.n_skipped, len(second.runs)) == (3, 1, 4)
    assert (second.runs["status"] == "ok").all() and kept.read_bytes() == before
    third = run_sweep(spec, out, scheduler=cluster.address, plots=False)
    assert (third.n_executed, third.n_skipped) == (0, 4)
    other = make_spec(PAPER, {"fish.length_mean_m": [0.55, 0.60]}, 2, SHORT)
    with pytest.raises(InputError, match="different sweep"):
        run_sweep(other, out, scheduler=cluster.address)


def test_worker_without_fmu_cache_gets_the_clients_fmus_and_does_not_compile(cluster, tmp_path: Path,
                                                                             builtin_fmus: dict[str, Path]) -> None:
    from distributed import Client

    from fishfmu.fmu.build import source_digest
    with Client(cluster.address) as client:  # the workers' cmake is the fake one: a build would be seen
        assert set(client.run(shutil.which, "cmake").values()) == {str(cluster.marker.parent / "cmake")}
    res = run_sweep(make_spec(PAPER, {}, 2, SHORT), tmp_path / "sweep", scheduler=cluster.address, plots=False)
    assert (res.runs["status"] == "ok").all()
    for name, client_fmu in builtin_fmus.items():
        assert (cluster.cache / source_digest(name) / f"{name}.fmu").read_bytes() == client_fmu.read_bytes()
    assert not cluster.marker.exists()
    assert sorted(p.name for p in cluster.cache.iterdir()) == sorted(source_digest(n) for n in builtin_fmus)


def test_mean_ci_matches_hand_computation() -> None:
    # x = 0.2, 0.4, 0.3, 0.5: mean 0.35, deviations -0.15, 0.05, -0.05, 0.15 -> sd = sqrt(0.05 / 3);
    # t(0.975, 3 degrees of freedom) = 3.182446 (t table) -> half width = 3.182446 * sd / 2
    ci = mean_ci([0.2, 0.4, None, 0.3, 0.5])
    sd = math.sqrt(0.05 / 3)
    half = 3.182446 * sd / 2
    assert (ci.n, ci.n_undefined) == (4, 1)
    assert ci.mean == pytest.approx(0.35, abs=1e-12) and ci.sd == pytest.approx(sd, rel=1e-12)
    assert ci.ci_low == pytest.approx(0.35 - half, rel=1e-6) and ci.ci_high == pytest.approx(0.35 + half, rel=1e-6)
    assert mean_ci([0.7]).ci_low is None and mean_ci([None]).mean is None


def test_wilson_bounds_solve_the_score_equation() -> None:
    # the Wilson bounds are the two p with (p_hat - p)^2 = z^2 p (1 - p) / n, z = 1.959964
    lo, hi = wilson_interval(10, 18)
    for p in (lo, hi):
        assert (10 / 18 - p) ** 2 == pytest.approx(1.959964 ** 2 * p * (1 - p) / 18, rel=1e-5)
    assert lo < 10 / 18 < hi and wilson_interval(0, 0) is None


def test_summary_leaves_out_failed_runs_and_pools_fish() -> None:
    import pandas as pd
    runs = pd.DataFrame({"p": [1, 1, 1], "status": ["ok", "ok", "failed"], "error": [None, None, "boom"],
                         "fish_in": [18, 18, None], "singulated": [9, 3, None], "singulation_rate": [0.5, 1 / 6, None]})
    row = summarise(runs, ["p"], ["singulation_rate"]).iloc[0]
    assert (row["n_ok"], row["n_failed"], row["errors"]) == (2, 1, "boom")
    assert row["singulation_rate_mean"] == pytest.approx(1 / 3) and row["singulation_rate_n"] == 2
    assert row["singulation_rate_pooled"] == pytest.approx(12 / 36)


def test_sweep_command_rejects_bad_input_with_exit_2(tmp_path: Path) -> None:
    for args in (["--param", "fish.count"], ["--param", "run.seed=1,2"], ["--param", "fish.count=3", "--seeds", "0"],
                 ["--param", "fish.nonsense=1,2"]):
        done = subprocess.run([sys.executable, "-m", "fishfmu.cli", "sweep", str(PAPER), "--out", str(tmp_path / "s"),
                               *args], capture_output=True, text=True, cwd=tmp_path)
        assert done.returncode == 2, (args, done.stderr)


def test_run_with_seeds_reports_means_and_checks_expect_on_them(tmp_path: Path) -> None:
    sets = [a for k, v in SHORT.items() for a in ("--set", f"{k}={v}")]
    done = subprocess.run([sys.executable, "-m", "fishfmu.cli", "run", str(PAPER), "--seeds", "2", "--workers", "2",
                           "--out", str(tmp_path / "mc"), *sets], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "CI": "1"})
    kpis = json.loads((tmp_path / "mc" / "kpis.json").read_text())
    # no fish reaches the outfeed in 4 s: the paper's "lost <= 0" bound fails on the mean (exit 1)
    assert done.returncode == 1, done.stdout + done.stderr
    assert kpis["seeds"] == [1, 2] and kpis["lost"] == 2.0 and kpis["expect"]["lost"]["ok"] is False
    assert kpis["statistics"]["fish_in"]["n"] == 2
    assert (tmp_path / "mc" / "seeds" / "runs.csv").is_file()



def test_a_scale_multiplies_the_scenarios_values_of_its_keys() -> None:
    """--scale speed=KEYS with --param speed=F: each key gets F times its value in paper_dump.toml
    (0.25/0.50/0.80/1.25 m/s), the same at every point and for every seed; other keys untouched."""
    from fishfmu.batch.sweep_spec import PointPreparer, point_overrides
    keys = [f"fmu[0].parameters.speed_{i}" for i in range(1, 5)]
    spec = make_spec(PAPER, {"speed": [0.5, 1.2], "fish.first_drop_s": [2.0]}, 1, {"fish.count": 3},
                     scales={"speed": keys})
    over = point_overrides(spec, {"speed": 0.5, "fish.first_drop_s": 2.0})
    assert [over[k] for k in keys] == pytest.approx([0.125, 0.25, 0.40, 0.625])
    assert over["fish.first_drop_s"] == 2.0 and over["fish.count"] == 3 and "speed" not in over
    sc = PointPreparer(spec).prepare({"speed": 1.2, "fish.first_drop_s": 2.0})
    assert [sc.fmu[0].parameters[f"speed_{i}"] for i in range(1, 5)] == pytest.approx([0.30, 0.60, 0.96, 1.50])
    # the point shares the base's unchanged tables, and is the very scenario loaded with its overrides
    from fishfmu.scenario.schema import load_scenario, resolved_toml
    alone = load_scenario(PAPER, point_overrides(spec, {"speed": 1.2, "fish.first_drop_s": 2.0}))
    assert resolved_toml(sc) == resolved_toml(alone)
    assert spec.definition()["scales"] == {"speed": keys}  # a resumed sweep with other scales is refused


def test_a_scale_on_a_key_that_is_not_a_number_or_not_swept_is_refused() -> None:
    with pytest.raises(InputError, match="not swept"):
        make_spec(PAPER, {"fish.count": [3]}, 1, scales={"speed": ["fmu[0].parameters.speed_1"]})
    with pytest.raises(InputError, match="not a number"):
        make_spec(PAPER, {"f": [1.0]}, 1, scales={"f": ["fish.drop"]})
    with pytest.raises(InputError, match="not set"):
        make_spec(PAPER, {"f": [1.0]}, 1, scales={"f": ["fmu[0].parameters.no_such"]})


# ---------------------------------------------------------------- preparing the points (issue 28)

def _count_calls(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[int]:
    """Wrap ``module.name`` so that each call is counted (the returned list's length)."""
    calls: list[int] = []
    original = getattr(module, name)

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_the_builtin_fmu_sources_are_hashed_once_per_process(monkeypatch, builtin_fmus) -> None:
    import fishfmu.fmu.build as fmu_build
    from fishfmu.fmu.build import builtin_fmu
    first = builtin_fmu("conveyor_drive")
    hashed = _count_calls(monkeypatch, fmu_build.hashlib, "sha256")
    read = _count_calls(monkeypatch, fmu_build.Path, "read_bytes")
    assert all(builtin_fmu("conveyor_drive") == first for _ in range(50))
    assert (len(hashed), len(read)) == (0, 0)


def test_a_sweep_prepares_each_point_once_and_per_point_only_what_differs(tmp_path: Path, monkeypatch,
                                                                            builtin_fmus) -> None:
    """40 values of one start value, the last outside the range the controller declares (speed_1 in [0, 2]): the
    scenario file is read and the wiring resolved once per preparation pass, not per point, every point is
    validated once (the probes of make_spec aside) and the bad one is still found, named by its key."""
    import fishfmu.cosim.preflight as preflight_module
    import fishfmu.scenario.schema as schema_module
    values = [round(0.2 + 0.01 * i, 2) for i in range(39)] + [2.5]
    validated = _count_calls(monkeypatch, schema_module, "validate")
    read = _count_calls(monkeypatch, schema_module, "read_toml")
    wired = _count_calls(monkeypatch, preflight_module, "resolve_wiring")
    spec = make_spec(PAPER, {"fmu[0].parameters.speed_1": values}, 1, SHORT)
    result = run_sweep(spec, tmp_path / "sw", max_runs=0, plots=False)
    assert len(validated) <= len(values) + 5, len(validated)  # was twice per point
    assert len(read) <= 3 and len(wired) <= 2, (len(read), len(wired))  # was once and twice per point
    failed = result.runs[result.runs["status"] == "failed"]
    assert list(failed["fmu[0].parameters.speed_1"]) == [2.5]
    assert "fmu[0].parameters.speed_1" in failed["error"].iloc[0] and "outside the range" in failed["error"].iloc[0]


def test_a_point_that_changes_the_wiring_is_checked_in_full(tmp_path: Path) -> None:
    spec = make_spec(PAPER, {"wiring.setpoints.c1": ["drive_c1.no_such", "drive_c1.speed_setpoint"]}, 1, SHORT)
    result = run_sweep(spec, tmp_path / "sw", max_runs=0, plots=False)
    failed = result.runs[result.runs["status"] == "failed"]
    assert list(failed["wiring.setpoints.c1"]) == ["drive_c1.no_such"]
    assert "wiring.setpoints.c1" in failed["error"].iloc[0]
    assert (result.runs["status"] == "failed").sum() == 1


def test_a_long_preparation_shows_its_progress(tmp_path: Path, capsys) -> None:
    spec = make_spec(PAPER, {"fish.length_mean_m": [0.55, 0.6, 0.65]}, 2, SHORT)
    run_sweep(spec, tmp_path / "sw", max_runs=0, plots=False, progress=True)
    err = capsys.readouterr().err
    assert "points checked" in err and "3/3" in err, err
