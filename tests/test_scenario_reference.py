"""docs/scenario-reference.md: generated from the schema, current, and covering every shipped key."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

from fishfmu.scenario.reference import COMMAND, scenario_reference

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = sorted((ROOT / "scenarios").glob("*.toml"))


@pytest.fixture(scope="module")
def reference() -> str:
    return scenario_reference()


def rows(text: str) -> dict[str, list[str]]:
    """key -> its cells (type, unit, default, range, description), read from the Markdown tables."""
    out = {}
    for line in text.splitlines():
        m = re.match(r"^\| `([^`]+)` \|(.*)\|$", line)
        if m:
            out[m.group(1)] = [c.strip() for c in re.split(r"(?<!\\)\|", m.group(2))]
    return out


def toml_keys(doc: Any, path: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every leaf key of a TOML document as a path; an array of tables adds ``[i]`` to its key."""
    if isinstance(doc, dict):
        return [k for name, value in doc.items() for k in toml_keys(value, path + (name,))]
    if isinstance(doc, list) and doc and all(isinstance(v, dict) for v in doc):
        indexed = path[:-1] + (path[-1] + "[i]",)
        return sorted({k for v in doc for k in toml_keys(v, indexed)})
    return [path]


def matches(pattern: str, key: tuple[str, ...]) -> bool:
    """``fmu[i].parameters.<variable>`` matches ('fmu[i]', 'parameters', 'n_belts')."""
    parts = pattern.split(".")
    return len(parts) == len(key) and all(p == k or (p.startswith("<") and p.endswith(">"))
                                          for p, k in zip(parts, key))


def test_committed_reference_is_current(reference: str) -> None:
    assert (ROOT / "docs" / "scenario-reference.md").read_text(encoding="utf-8") == reference, (
        f"docs/scenario-reference.md is out of date with the scenario schema; regenerate it: {COMMAND}")


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda p: p.name)
def test_every_key_of_a_shipped_scenario_is_in_the_reference(scenario: Path, reference: str) -> None:
    patterns = list(rows(reference))
    keys = toml_keys(tomllib.loads(scenario.read_text(encoding="utf-8")))
    # the walk reached arrays of tables, free keys and nested tables (every shipped scenario has a line and bounds;
    # the controller's parameters are in those that have a controller FMU)
    assert {("line", "conveyors[i]", "length_m"), ("expect", "lost", "max")} <= set(keys)
    if any(f.get("builtin") == "singulation_controller" for f in tomllib.loads(scenario.read_text("utf-8"))["fmu"]):
        assert ("fmu[i]", "parameters", "speed_1") in set(keys)
    missing = [".".join(k) for k in keys if not any(matches(p, k) for p in patterns)]
    assert not missing, f"{scenario.name}: keys not in docs/scenario-reference.md: {missing}"


def test_spot_checks_worked_out_by_hand(reference: str) -> None:
    table = rows(reference)
    # run.comm_step_s: float, seconds, default 0.01, 0.001 <= x <= 0.1, with its description
    assert table["run.comm_step_s"][:4] == ["float", "s", "`0.01`", "≥ 0.001, ≤ 0.1"]
    assert "base communication step" in table["run.comm_step_s"][4]
    # fish.count: int, no unit, default 18, 1..2000, the paper's batch
    assert table["fish.count"][:4] == ["int", "", "`18`", "≥ 1, ≤ 2000"]
    assert "18" in table["fish.count"][4]
    # required keys, optional keys, Literal, units from the suffix and from the description
    assert table["line.conveyors[i].length_m"][:4] == ["float", "m", "required", "> 0.05, ≤ 200"]
    assert table["kpi.infeed_photoeye"][0] == "str, optional" and table["kpi.infeed_photoeye"][2] == "unset"
    assert table["kpi.infeed_photoeye"][3].startswith("1 to 64 characters, pattern")
    assert table["run.coupling"][0] == 'one of "gauss-seidel", "jacobi"'
    assert table["fish.hours_post_mortem"][1] == "h"
    assert table["plant.numerics.contact_omega_rad_s"][1] == "rad/s"
    assert table["line.conveyors"][3] == "1 to 64 entries"
    assert "fmu[i].parameters.<variable>" in table and "expect.<kpi>.min" in table
    # sections per table, and no key that the schema does not have
    for heading in ("[run]", "[line]", "[[line.conveyors]]", "[fish]", "[plant]", "[plant.numerics]",
                    "[plant.extensions.rigor_mortis]", "[[fmu]]", "[wiring]", "[[event]]", "[kpi]", "[expect]"):
        assert f"## `{heading}`" in reference
    assert "run.comm_step" not in table and "fish.counts" not in table
    assert not any(k.endswith(".id") and k.startswith("run.") for k in table)


def test_every_key_has_a_description(reference: str) -> None:
    undocumented = [k for k, cells in rows(reference).items() if not cells[4]]
    assert not undocumented, f"give these fields a description (Field(description=...)): {undocumented}"
