"""One home for each shared thing (issue 14): the KPI keys, "did you mean" hints, run_info.json,
the JUnit writer and JSON cleaning, each checked on hand-made inputs."""

from __future__ import annotations

import json
import math
import signal
from types import SimpleNamespace
from xml.etree import ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from plant.contract.kpis import KPI_KEYS, KPIS, SHOWN_KPI_KEYS, kpi_keys, kpis_from_passages
from plant.validation import suggest

from fishfmu.output.junit import junit_args_of_run, write_junit

from fishfmu.output.atomic import json_safe
from fishfmu.output.run_folder import MARKER, mark_partial, write_run_info
from fishfmu.cosim.runner import ExpectResult


# ----------------------------------------------------------------------------- KPI keys
def test_kpi_keys_are_what_the_computation_returns_in_its_order() -> None:
    p = pd.DataFrame({"t_start_s": [10.0, 12.0, 12.5], "t_end_s": [10.5, 12.75, 13.0]})
    k = kpis_from_passages(p, n_fish=4, first_drop_t_s=1.0, belt_speed_fn=lambda t: np.full(len(t), 2.0),
                           min_gap_m=0.05)
    assert tuple(key for key in k if key in KPI_KEYS) == KPI_KEYS
    numeric = {key for key, v in k.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    assert numeric - set(KPI_KEYS) == {"estimated_fish", "min_gap_m"}  # settings and bookkeeping, not KPIs
    assert all(kpi.unit and kpi.description for kpi in KPIS)


def test_every_list_of_kpis_comes_from_plant_kpis() -> None:
    from fishfmu.analysis import compare
    from fishfmu.batch import sweep, sweep_report
    from fishfmu.scenario import schema as scenario
    assert scenario.KPI_KEYS is KPI_KEYS and sweep.KPI_KEYS is KPI_KEYS
    assert sorted(SHOWN_KPI_KEYS) == sorted(KPI_KEYS)
    assert SHOWN_KPI_KEYS[-3:] == ("gap_min_m", "gap_p10_m", "gap_median_m")  # by quantile, for a person
    assert KPI_KEYS[-3:] == ("gap_min_m", "gap_median_m", "gap_p10_m")  # the runs.csv columns, unchanged
    assert set(compare.KPI_KEYS) < set(KPI_KEYS) and "fish_in" not in compare.KPI_KEYS
    assert set(sweep_report.PLOT_KPIS) <= set(KPI_KEYS)
    with pytest.raises(KeyError, match="singulaton_rate"):
        kpi_keys("fpm_out", "singulaton_rate")


# ----------------------------------------------------------------------------- did you mean
@pytest.mark.parametrize(("name", "known", "kwargs", "expected"), [
    ("cuont", ["count", "seed"], {}, "; did you mean 'count'?"),
    ("singulaton_rate", KPI_KEYS, {"allowed": "KPIs"}, "; did you mean 'singulation_rate'?"),
    ("zzz", KPI_KEYS, {"allowed": "KPIs"}, "; KPIs: " + ", ".join(KPI_KEYS)),
    ("zzz", [], {"allowed": "allowed keys"}, ""),
    ("zzz", ["count"], {}, ""),
    ("c1.sped", {"c1.speed": 1}, {"prefix": "plant."}, "; did you mean 'plant.c1.speed'?"),
    ("belt_sped", ["belt_speed"], {"template": " (did you mean '{}'?)"}, " (did you mean 'belt_speed'?)"),
    ("hours_postmortem", ["hours_post_mortem", "id"], {"cutoff": 0.8}, "; did you mean 'hours_post_mortem'?"),
    ("hours", ["hours_post_mortem"], {"cutoff": 0.8}, ""),
])
def test_suggest(name, known, kwargs, expected) -> None:
    assert suggest(name, known, **kwargs) == expected


# ----------------------------------------------------------------------------- JUnit
EXPECT = [ExpectResult("lost", 2.0, None, 0.0), ExpectResult("singulation_rate", 0.5, 0.4, None),
          ExpectResult("fpm_in", None, 10.0, None)]


def _suite(path) -> ET.Element:
    root = ET.parse(path).getroot()
    assert root.tag == "testsuite"
    return root


@pytest.mark.parametrize("status", ["ok", "failed"])
def test_junit_of_a_single_run(tmp_path, status) -> None:
    result = SimpleNamespace(scenario=SimpleNamespace(run=SimpleNamespace(name="paper", seed=7)), expect=EXPECT,
                             status=status, error=None if status == "ok" else "FMU 'drive' crashed", wall_s=1.5)
    write_junit(tmp_path / "j.xml", **junit_args_of_run(result, "s.toml"))
    suite = _suite(tmp_path / "j.xml")
    assert suite.attrib == {"name": "fishfmu:paper", "tests": "3", "failures": "2",
                            "errors": "0" if status == "ok" else "1", "time": "1.500"}
    assert {p.get("name"): p.get("value") for p in suite.iter("property")} == {"scenario": "s.toml", "seed": "7"}
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ([] if status == "ok" else ["simulation"]) + [
        "expect.lost", "expect.singulation_rate", "expect.fpm_in"]
    assert len(suite.findall("testcase/failure")) == 2 and len(suite.findall("testcase/error")) == (status != "ok")
    assert suite.find("testcase/system-out").get("message") is None  # a passed bound: the text only


def test_junit_of_seeds(tmp_path) -> None:
    write_junit(tmp_path / "j.xml", "fishfmu:paper:seeds", "fishfmu.seeds", EXPECT, on="mean",
                error=("1 runs failed", "seed 2: boom"))
    suite = _suite(tmp_path / "j.xml")
    assert suite.attrib == {"name": "fishfmu:paper:seeds", "tests": "3", "failures": "2", "errors": "1"}
    assert suite.find("properties") is None
    assert suite.find("testcase/error").text == "seed 2: boom"
    assert [f.get("message") for f in suite.findall("testcase/failure")] == [
        "mean lost = 2 is above the maximum 0 by 2", "mean fpm_in is undefined in this run"]
    assert suite.find("testcase/system-out").get("message") == "mean singulation_rate = 0.5 within [0.4, None]"
    assert all(c.get("classname") == "fishfmu.seeds" for c in suite.iter("testcase"))


# ----------------------------------------------------------------------------- run_info.json, JSON cleaning
def test_json_safe() -> None:
    doc = json_safe({"a": np.float64("nan"), 2: (np.int64(3), math.inf, np.bool_(False)), "b": [{"c": np.float32(0.5)}]})
    assert doc == {"a": None, "2": [3, None, False], "b": [{"c": 0.5}]}
    assert type(doc["2"][0]) is int and type(doc["b"][0]["c"]) is float
    json.dumps(doc, allow_nan=False)


def test_run_info_is_written_json_safe_and_kept_by_mark_partial(tmp_path) -> None:
    write_run_info(tmp_path, "running", command="sweep", n_done=np.int64(4), wall_s=float("nan"))
    assert json.loads((tmp_path / MARKER).read_text()) == {"status": "running", "command": "sweep", "n_done": 4,
                                                           "wall_s": None}
    mark_partial(tmp_path, signal.SIGTERM)
    assert json.loads((tmp_path / MARKER).read_text()) == {"status": "partial", "command": "sweep", "n_done": 4,
                                                           "wall_s": None, "stopped_by": "SIGTERM"}
