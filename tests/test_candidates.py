"""The registry of candidate causes (fishfmu.analysis.candidates): fragments, the off value, the rigor formula.

Small hand-made inputs only: no simulation, a second or two.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from plant.fish.extensions import RigorMortis
from plant.sim.params import PlantParams

from fishfmu.analysis.candidates import CANDIDATES, fragment
from fishfmu.analysis.levels import rigor_index, rigor_limit_loss
from fishfmu.scenario.schema import load_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "paper_dump.toml"

VALUES = {  # a fitted value per parameter (exact in four digits), and what the plant (or drive) must then hold
    "mucus_friction": ({"gain": 1.5, "time_constant_h": 8.0, "friction_level": 0.6},  # fresh fish slide more
                       {"extensions.mucus_friction.gain": 1.5, "extensions.mucus_friction.time_constant_h": 8.0,
                        "friction.fish_belt": lambda base: 0.6 * base.friction.fish_belt}),
    "rigor_mortis": ({"stiffness_gain": 3.0, "peak_h": 12.0, "width_h": 40.0},  # limit loss 0.6 * 3 / (3 + 3)
                     {"extensions.rigor_mortis.stiffness_gain": 3.0, "extensions.rigor_mortis.limit_loss": 0.3,
                      "extensions.rigor_mortis.peak_h": 12.0, "extensions.rigor_mortis.width_h": 40.0}),
    "directional_friction": ({"asymmetry": 0.3}, {"extensions.direction_friction.head": 0.7,
                                                  "extensions.direction_friction.tail": 1.3}),
    "adhesion": ({"force_n": 2.5}, {"extensions.adhesion.force_n": 2.5}),
    "drive_droop": ({"belt_slip": 5e-4}, {"belt_slip": 5e-4}),
    "photoeye_latency": ({"latency_s": 0.03}, {"latency_s": 0.03}),
    "guide_wear": ({"rise": 2.5}, {"extensions.guide_wear.rise": 2.5}),
}


def _get(obj, dotted: str):
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


def _flatten(table: dict, prefix: str = "") -> dict[str, object]:
    out = {}
    for k, v in table.items():
        out.update(_flatten(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def _drive_defaults() -> dict[str, float]:
    spec = tomllib.loads((ROOT / "fishfmu" / "fmu" / "sources" / "conveyor_drive" / "variables.toml").read_text())
    return {v["name"]: v for v in spec["variable"]}


def test_every_candidate_has_hand_values_here():
    assert set(VALUES) == set(CANDIDATES), "a new candidate needs its values in VALUES (and is then tested below)"


@pytest.mark.parametrize("name", sorted(CANDIDATES))
def test_fragment_parses_and_sets_the_parameters_in_a_scenario(name: str):
    cand = CANDIDATES[name]
    values, expected = VALUES[name]
    base = load_scenario(SCENARIO).plant
    text = fragment(name, values, base)
    assert text.startswith(f"# fitted by fishfmu diagnose: {cand.description}\n")
    if cand.acts_on == "drive":  # FMU parameters: commented out, to paste into each conveyor_drive instance
        assert tomllib.loads(text) == {}
        body = "".join(line[2:] + "\n" for line in text.splitlines() if line.startswith("# [") or " = " in line)
        params = tomllib.loads(body)["fmu"]["parameters"]
        assert params == pytest.approx(expected)
        drive = _drive_defaults()
        assert all(drive[k]["min"] <= v <= drive[k]["max"] for k, v in params.items())
        return
    if cand.acts_on == "sensor":  # keys of each photo-eye's table: commented out, pasted into each [[line.photoeyes]]
        assert tomllib.loads(text) == {}
        body = "".join(line[2:] + "\n" for line in text.splitlines() if line.startswith("# [") or " = " in line)
        eye = tomllib.loads(body)["line"]["photoeyes"][0]
        assert eye == pytest.approx(expected)
        # and a line whose photo-eyes carry them validates, with the values read back
        scenario = load_scenario(SCENARIO)
        line = scenario.line.model_dump()
        line["photoeyes"] = [{**p, **eye} for p in line["photoeyes"]]
        assert all(p.latency_s == pytest.approx(expected["latency_s"])
                   for p in type(scenario.line).model_validate(line).photoeyes)
        return
    doc = tomllib.loads(text)
    assert list(doc) == ["plant"]
    overrides = {f"plant.{k}": v for k, v in _flatten(doc["plant"]).items()}
    assert set(overrides) == {f"plant.{k}" for k in expected}  # the fragment sets exactly these
    loaded = load_scenario(SCENARIO, overrides).plant  # the fragment's tables into the scenario's [plant]
    for key, want in expected.items():
        want = want(base) if callable(want) else want
        assert _get(loaded, key) == pytest.approx(want, rel=1e-4), key
    # and what diagnose simulated with these values is what the fragment gives
    applied = cand.params(base, *[values[k] for k in cand.parameters])
    for key in expected:
        assert _get(applied, key) == pytest.approx(_get(loaded, key), rel=1e-4), key


def test_no_cause_has_a_fragment_that_says_so():
    text = fragment("none", {}, PlantParams())
    assert tomllib.loads(text) == {} and "no extension" in text


@pytest.mark.parametrize("name", sorted(CANDIDATES))
def test_the_off_value_leaves_the_defaults_unchanged(name: str):
    cand = CANDIDATES[name]
    default = PlantParams()
    assert cand.params(default, cand.off).model_dump() == PlantParams().model_dump()
    # (the off value is the strength's, the first parameter; the others, such as rigor's timing, keep the model's)
    assert default.model_dump() == PlantParams().model_dump()  # the base itself is never changed
    drive = _drive_defaults()
    assert {k: drive[k]["start"] for k in cand.drive_parameters(cand.off)} == cand.drive_parameters(cand.off)
    assert cand.grid == tuple(sorted(cand.grid)) and cand.off not in cand.grid
    assert all(cand.bounds[0] <= v <= cand.bounds[1] for v in (cand.off, *cand.grid))


def test_a_strength_changes_something():
    for cand in CANDIDATES.values():
        v = cand.grid[-1] if cand.grid else cand.bounds[1]
        changed = (cand.params(PlantParams(), v).model_dump() != PlantParams().model_dump()
                   or cand.drive_parameters(v) != cand.drive_parameters(cand.off)
                   or cand.photoeye_parameters(v) != cand.photoeye_parameters(cand.off))
        assert changed, cand.name


def test_rigor_formula_at_two_hours_post_mortem():
    # ((2 - 24) / 20)^2 = 1.21: the index is exp(-1.21) = 0.2981973, the same in the level models and in the plant
    assert rigor_index(np.array([2.0]))[0] == pytest.approx(0.29819727942988739, rel=1e-12)
    assert RigorMortis().index(2.0) == pytest.approx(0.29819727942988739, rel=1e-12)
    assert rigor_index(np.array([24.0]))[0] == 1.0
    # the candidate at strength 3: stiffness x (1 + 3 R), range lost 0.6 * 3 / (3 + 3) = 0.3 at full rigor
    assert rigor_limit_loss(3.0) == pytest.approx(0.3) and rigor_limit_loss(0.0) == 0.0
    rigor = CANDIDATES["rigor_mortis"].params(PlantParams(), 3.0).extensions.rigor_mortis
    stiffness, limits = rigor.joint_factors(2.0)
    assert stiffness == pytest.approx(1.894591838, rel=1e-9)
    assert limits == pytest.approx(0.9105408162, rel=1e-9)
    assert math.isclose(rigor.limit_loss, 0.3)
