"""Property tests of the scenario loader: whatever the file holds, loading it either gives a scenario
or raises InputError with one line naming the file; never any other exception.

Generated files: arbitrary text, arbitrary TOML documents, and the shipped scenarios mutated (keys
deleted, renamed or added, values replaced by values of any type, tables and arrays emptied or
duplicated), plus random ``--set`` overrides.  A scenario that loads must also either wire up
against the built-in FMUs or be refused by the wiring check with an InputError.  Derandomized and
without an example database, so every run tries the same examples and writes nothing.
"""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plant.errors import InputError

from fishfmu.scenario.schema import Scenario, load_scenario

ROOT = Path(__file__).parents[1]
SHIPPED = {p.name: tomllib.loads(p.read_text()) for p in sorted((ROOT / "scenarios").glob("*.toml"))}
PROFILE = settings(max_examples=120, deadline=None, derandomize=True, database=None,
                   suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                          HealthCheck.function_scoped_fixture])


def _all_keys(node: Any, out: set[str]) -> set[str]:
    if isinstance(node, dict):
        for k, v in node.items():
            out.add(k)
            _all_keys(v, out)
    elif isinstance(node, list):
        for v in node:
            _all_keys(v, out)
    return out


KEYS = sorted(set().union(*(_all_keys(d, set()) for d in SHIPPED.values())))
key_text = st.one_of(st.sampled_from(KEYS), st.text(min_size=1, max_size=12))
scalars = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1), st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(), st.text(max_size=20), st.sampled_from([0, -1, 1e308, -1e-9, 1e9, "plant.c1.speed",
                                                           "drive_c1.belt_speed -> plant.c1.speed", ""]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(key_text, inner, max_size=4)), max_leaves=12)


def _loads_or_input_error(path: Path, overrides: dict[str, Any] | None = None) -> Scenario | None:
    """Load; an InputError must be one line naming the file.  Anything else fails the test."""
    try:
        return load_scenario(path, overrides)
    except InputError as exc:
        text = str(exc)
        assert "\n" not in text, text
        assert str(path) in text, text
        return None


@pytest.fixture(scope="module")
def builtin_variables(builtin_fmus: dict[str, Path]):
    """Variables and direct-feedthrough outputs of each built-in FMU (opened once)."""
    from fishfmu.fmu.archive import open_fmu
    from fishfmu.scenario.order import direct_feedthrough
    out = {}
    for name, path in builtin_fmus.items():
        with open_fmu(path) as fmu:
            out[name] = (fmu.variables, direct_feedthrough(fmu.model_description))
    return out


def _wires_or_input_error(sc: Scenario, path: Path, builtin_variables) -> None:
    from fishfmu.scenario.wiring import resolve_wiring
    if any(f.builtin is None for f in sc.fmu):
        return  # FMUs by path: their files are the FMU corpus's business (test_bad_input)
    variables = {f.name: builtin_variables[f.builtin][0] for f in sc.fmu}
    feedthrough = {f.name: builtin_variables[f.builtin][1] for f in sc.fmu}
    try:
        resolve_wiring(sc, variables, str(path), feedthrough)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc), str(exc)


# ---------------------------------------------------------------- generated files

@PROFILE
@given(text=st.text(max_size=300))
def test_any_text_loads_or_is_an_input_error(tmp_path: Path, text: str) -> None:
    path = tmp_path / "any.toml"
    path.write_text(text, encoding="utf-8", errors="surrogateescape")
    _loads_or_input_error(path)


@PROFILE
@given(doc=st.dictionaries(key_text, values, max_size=8))
def test_any_toml_document_loads_or_is_an_input_error(tmp_path: Path, doc: dict) -> None:
    path = tmp_path / "doc.toml"
    try:
        path.write_text(tomli_w.dumps(doc))
    except (TypeError, ValueError):
        return  # not representable in TOML (e.g. a lone surrogate): no such file can exist
    _loads_or_input_error(path)


# ---------------------------------------------------------------- mutated shipped scenarios

def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


def _parent(doc: Any, path: tuple) -> tuple[Any, Any]:
    node = doc
    for part in path[:-1]:
        node = node[part]
    return node, path[-1]


@st.composite
def mutated(draw) -> tuple[str, dict]:
    name = draw(st.sampled_from(sorted(SHIPPED)))
    doc = copy.deepcopy(SHIPPED[name])
    for _ in range(draw(st.integers(min_value=1, max_value=4))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _parent(doc, path)
        kind = draw(st.sampled_from(["delete", "replace", "rename", "add", "scale", "empty", "duplicate"]))
        if kind == "delete":
            del parent[key]
        elif kind == "replace":
            parent[key] = draw(values)
        elif kind == "rename" and isinstance(parent, dict):
            new = draw(st.one_of(st.sampled_from(KEYS), st.builds(lambda k, c: k[:-1] + c if len(k) > 1 else k + c,
                                                                  st.just(str(key)), st.characters(min_codepoint=97,
                                                                                                   max_codepoint=122))))
            parent[new] = parent.pop(key)
        elif kind == "add" and isinstance(parent, dict):
            parent[draw(key_text)] = draw(values)
        elif kind == "scale" and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            factor = draw(st.sampled_from([-1, 0, 1e-6, 1000, math.inf, math.nan]))
            parent[key] = parent[key] * factor
        elif kind == "empty" and isinstance(parent[key], (list, dict)):
            parent[key] = type(parent[key])()
        elif kind == "duplicate" and isinstance(parent[key], list) and parent[key]:
            parent[key] = parent[key] + parent[key][:1]
    return name, doc


@PROFILE
@given(case=mutated())
def test_mutated_shipped_scenario_loads_or_is_an_input_error(tmp_path: Path, case: tuple[str, dict],
                                                             builtin_variables) -> None:
    name, doc = case
    path = tmp_path / name
    try:
        path.write_text(tomli_w.dumps(doc))
    except (TypeError, ValueError):
        return
    sc = _loads_or_input_error(path)
    if sc is not None:
        _wires_or_input_error(sc, path, builtin_variables)


override_keys = st.one_of(
    st.sampled_from(["fish.count", "run.seed", "fmu[0].parameters.speed_1", "fmu[9].path", "line.conveyors[0].id",
                     "run", "wiring.connections[0]", "expect.lost.max", "a..b", "[0]", "fish.count[2]", "kpi"]),
    st.lists(key_text, min_size=1, max_size=3).map(".".join), st.text(max_size=15))


@PROFILE
@given(overrides=st.dictionaries(override_keys, values, max_size=3))
def test_overrides_on_a_shipped_scenario_load_or_are_an_input_error(overrides: dict) -> None:
    _loads_or_input_error(ROOT / "scenarios" / "paper_dump.toml", overrides)


def test_the_shipped_scenarios_themselves_load_and_wire(builtin_variables) -> None:
    for name in SHIPPED:
        path = ROOT / "scenarios" / name
        sc = load_scenario(path)
        _wires_or_input_error(sc, path, builtin_variables)
